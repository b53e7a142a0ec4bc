//! A release of `gonio` may carry the firmware image it was built with, for `gonio flash`
//! with no argument: set `GONIO_FIRMWARE_IMAGE` to the board's ELF at build time. Without
//! it, `gonio flash` asks for the image's path.
use std::path::PathBuf;

fn main() {
    println!("cargo:rerun-if-env-changed=GONIO_FIRMWARE_IMAGE");
    let out = PathBuf::from(std::env::var_os("OUT_DIR").expect("cargo sets OUT_DIR"));
    let target = out.join("firmware_image.rs");
    let code = match std::env::var_os("GONIO_FIRMWARE_IMAGE").filter(|p| !p.is_empty()) {
        Some(path) => {
            let path = PathBuf::from(path);
            let path = std::fs::canonicalize(&path)
                .unwrap_or_else(|e| panic!("GONIO_FIRMWARE_IMAGE={}: {e}", path.display()));
            println!("cargo:rerun-if-changed={}", path.display());
            format!(
                "/// The firmware image built into this release (`GONIO_FIRMWARE_IMAGE`).\npub const BUILT_IN: Option<(&str, &[u8])> = Some(({:?}, include_bytes!({:?})));\n",
                path.display().to_string(),
                path.display().to_string()
            )
        }
        None => "/// No firmware image was built into this release (`GONIO_FIRMWARE_IMAGE` unset).\npub const BUILT_IN: Option<(&str, &[u8])> = None;\n".to_string(),
    };
    std::fs::write(&target, code).expect("write firmware_image.rs to OUT_DIR");
}
