//! The scenarios of `firmware::scenarios` on this machine, one line each with the digest of
//! what the device sent: `.ci/qemu-tests` compares these lines with the same scenarios
//! compiled for the Cortex-M4 and run under QEMU (the same bytes, or the target differs).
//!
//! `cargo run -p firmware --example scenarios`

fn main() {
    let mut failed = 0;
    for scenario in firmware::scenarios::SCENARIOS {
        match (scenario.run)() {
            Ok(digest) => println!("scenario {} ok digest {digest:08x}", scenario.name),
            Err(failure) => {
                failed += 1;
                println!(
                    "scenario {} FAILED: {} (scenarios.rs:{})",
                    scenario.name, failure.what, failure.line
                );
            }
        }
    }
    std::process::exit(i32::from(failed > 0));
}
