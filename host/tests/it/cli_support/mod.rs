//! Running the `gonio` binary from the tests, as a user would: one copy of the helpers
//! for every test crate that does.
#![allow(dead_code)]
use std::path::PathBuf;
use std::process::{Command, Output, Stdio};

/// `gonio ARGS…` with nothing on standard input, to its end.
pub fn gonio(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_gonio"))
        .args(args)
        .stdin(Stdio::null())
        .output()
        .expect("run gonio")
}

/// A fresh folder path for one test (`gonio-PREFIX-PID-NAME` in the temporary folder),
/// removed first if an earlier run left it.
pub fn temp_dir(prefix: &str, name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("gonio-{prefix}-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

/// What a run printed on standard error.
pub fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}
