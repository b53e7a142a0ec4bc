//! Reaching the instrument: the request/reply link, the serial port, the simulated
//! instrument in process, and the calibration that turns its readings into radiance
//! factors; and putting firmware on it (`gonio flash`): the image's checks, the steps of
//! flashing, and probe-rs behind them.
pub mod calibration;
pub mod firmware_image;
pub mod flash;
pub mod link;
pub mod probe;
pub mod profile;
pub mod selftest;
pub mod serial;
pub mod sim;
