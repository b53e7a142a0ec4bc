//! `gonio measure` in the test's own process, into folders in RAM: the sheet, resume and
//! bounds tests kill, interrupt and resume it at chosen writes ([`Crash`]).
use crate::measure_args::parse_args;
use host::measure::{Measured, measure_with};
use host::output::folder::store::{Crash, StoreOptions};
use host::session::{Operator, SimulatedOperator};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::AtomicBool;

/// A fresh folder `gonio-PREFIX-PID-NAME` in /dev/shm (else the temporary folder): many
/// small writes, each fsync'ed, are the tests' cost on a disk.
pub fn ram_dir(prefix: &str, name: &str) -> PathBuf {
    let ram = Path::new("/dev/shm");
    let base = if ram.is_dir() {
        ram.to_path_buf()
    } else {
        std::env::temp_dir()
    };
    let dir = base.join(format!("gonio-{prefix}-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

/// `gonio measure ARGS` with `operator` answering the prompts and `crash` injected.
pub fn measure_as(
    args: &[String],
    operator: &mut dyn Operator,
    crash: Option<Crash>,
) -> anyhow::Result<Measured> {
    let args = parse_args(args).expect("arguments");
    measure_with(
        &args,
        operator,
        Arc::new(AtomicBool::new(false)),
        StoreOptions {
            crash,
            ..Default::default()
        },
    )
}

/// `gonio measure LIST`, the simulated operator answering.
pub fn measure(list: &[&str], crash: Option<Crash>) -> anyhow::Result<Measured> {
    let args: Vec<String> = list.iter().map(|s| s.to_string()).collect();
    measure_as(&args, &mut SimulatedOperator, crash)
}
