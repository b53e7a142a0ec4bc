//! Reaching the instrument: the request/reply link, the serial port, the simulated
//! instrument in process, and the calibration that turns its readings into radiance
//! factors.
pub mod calibration;
pub mod link;
pub mod serial;
pub mod sim;
