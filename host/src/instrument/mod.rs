//! Reaching the instrument: the request/reply link, the serial port, the simulated
//! instrument in process, and the calibration that turns its readings into radiance
//! factors; and putting firmware on it (`gonio flash`): the image's checks, the steps of
//! flashing, and probe-rs behind them; the instrument's profile (`gonio characterize`).
pub mod calibration;
pub mod firmware_image;
pub mod flash;
pub mod link;
pub mod probe;
pub mod profile;
pub mod selftest;
pub mod serial;
pub mod sim;

/// gonio's folder of a user's data: `$XDG_DATA_HOME/gonio`, else
/// `$HOME/.local/share/gonio` (the XDG base-directory rule, computed from the environment
/// on every platform so the place is the same wherever gonio runs): the library and the
/// installed instrument profiles live there. `None` when neither variable is set.
pub fn data_dir() -> Option<std::path::PathBuf> {
    let nonempty = |name: &str| {
        std::env::var_os(name)
            .filter(|v| !v.is_empty())
            .map(std::path::PathBuf::from)
    };
    // XDG says a relative XDG_DATA_HOME is invalid and to be ignored.
    let base = nonempty("XDG_DATA_HOME")
        .filter(|p| p.is_absolute())
        .or_else(|| nonempty("HOME").map(|home| home.join(".local").join("share")))?;
    Some(base.join("gonio"))
}
