//! Link scripts: `memory.x` comes from embassy-stm32 (feature `memory-x`, the F411CE's
//! 512 KiB flash / 128 KiB RAM), `link.x` from cortex-m-rt, `defmt.x` from defmt.
//! They are passed as plain linker arguments so that both rust-lld (the default for
//! thumbv7em-none-eabihf) and a system `ld.lld` (the Debian CI path) understand them.
fn main() {
    println!("cargo:rustc-link-arg-bins=--nmagic");
    println!("cargo:rustc-link-arg-bins=-Tlink.x");
    println!("cargo:rustc-link-arg-bins=-Tdefmt.x");
    println!("cargo:rerun-if-changed=build.rs");
}
