//! Link scripts: `memory.x` is this crate's (the flipped layout: stack at the bottom of
//! the SRAM, see the file), `link.x` from cortex-m-rt, `defmt.x` from defmt, and
//! `gonio-info.x` this crate's (`.gonio.info` kept out of flash, see the file).
//! They are passed as plain linker arguments so that both rust-lld (the default for
//! thumbv7em-none-eabihf) and a system `ld.lld` (the Debian CI path) understand them.
use std::path::PathBuf;

fn main() {
    // link.x INCLUDEs memory.x from the linker's search path: put it in OUT_DIR.
    let out = PathBuf::from(std::env::var_os("OUT_DIR").expect("cargo sets OUT_DIR"));
    std::fs::write(out.join("memory.x"), include_bytes!("memory.x"))
        .expect("write memory.x to OUT_DIR");
    println!("cargo:rustc-link-search={}", out.display());
    std::fs::write(out.join("gonio-info.x"), include_bytes!("gonio-info.x"))
        .expect("write gonio-info.x to OUT_DIR");
    println!("cargo:rerun-if-changed=memory.x");
    println!("cargo:rerun-if-changed=gonio-info.x");
    println!("cargo:rustc-link-arg-bins=--nmagic");
    println!("cargo:rustc-link-arg-bins=-Tlink.x");
    println!("cargo:rustc-link-arg-bins=-Tdefmt.x");
    println!("cargo:rustc-link-arg-bins=-Tgonio-info.x");
    println!("cargo:rerun-if-changed=build.rs");
}
