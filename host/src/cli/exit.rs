//! Exit codes of `gonio`, the same for every subcommand (README, "Exit codes").
use std::process::ExitCode;

/// The job was done and its result is clean (`ok`).
pub const OK: u8 = 0;
/// The job failed: bad input, an instrument that could not be reached or kept, a file
/// that could not be written. The message says what and where; nothing measured is lost.
pub const FAILED: u8 = 1;
/// The command line was wrong: clap's refusals (an unknown option, a missing argument, a
/// value not of its type or range) and a value refused later ([`host::UsageError`]: out of
/// the instrument's range, an unknown sample name).
pub const USAGE: u8 = 2;
/// The job was done but its result is flagged (`ok` is false): read the flags.
pub const FLAGGED: u8 = 3;
/// The user interrupted it (Ctrl-C); the session can be resumed.
pub const INTERRUPTED: u8 = 130;

/// The exit code of a finished result: [`OK`] when clean, else [`FLAGGED`].
pub fn of_result(ok: bool) -> ExitCode {
    ExitCode::from(if ok { OK } else { FLAGGED })
}
