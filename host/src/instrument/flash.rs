//! Writing a checked firmware image to the instrument and seeing it come up: the steps of
//! `gonio flash` after the image's checks ([`super::firmware_image`]).
//!
//! The probe is behind [`Flasher`] (probe-rs's in [`super::probe`], a recording fake in the
//! tests), and the instrument that enumerates after the reset behind a finder closure, so
//! the order of the steps, the progress reported and every failure are tested without
//! hardware: find exactly one probe, attach, erase and program, verify, reset, then wait
//! (bounded) for the instrument and make the handshake, which must report the version just
//! flashed.
use super::firmware_image::FirmwareImage;
use super::link::{Client, LinkError, RetryPolicy, Transport};
use protocol::DeviceInfo;
use std::time::{Duration, Instant};

/// A debug probe found on USB.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ProbeDescription {
    /// What it is (probe-rs's identifier, e.g. "STLink V2").
    pub identifier: String,
    /// USB vendor id.
    pub vendor_id: u16,
    /// USB product id.
    pub product_id: u16,
    /// USB serial number, if it has one.
    pub serial_number: Option<String>,
}

impl std::fmt::Display for ProbeDescription {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} (USB {:04x}:{:04x}",
            self.identifier, self.vendor_id, self.product_id
        )?;
        if let Some(serial) = &self.serial_number {
            write!(f, ", serial {serial}")?;
        }
        write!(f, ")")
    }
}

/// A step of writing the flash, as progress is reported.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FlashStep {
    /// Erasing the sectors the image needs.
    Erase,
    /// Writing the image.
    Program,
    /// Reading the flash back and comparing it with the image.
    Verify,
}

impl FlashStep {
    /// For people.
    pub fn name(self) -> &'static str {
        match self {
            FlashStep::Erase => "erasing",
            FlashStep::Program => "programming",
            FlashStep::Verify => "verifying",
        }
    }
}

/// Progress of a [`FlashStep`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FlashProgress {
    /// The step begins; its size in bytes, when known.
    Started {
        /// Which step.
        step: FlashStep,
        /// Its bytes.
        total_bytes: Option<u64>,
    },
    /// `bytes` more of the step are done.
    Advanced {
        /// Which step.
        step: FlashStep,
        /// Bytes done since the last report.
        bytes: u64,
    },
    /// The step is done.
    Finished(FlashStep),
    /// The step failed (the error follows from the call).
    Failed(FlashStep),
}

/// The probe's side of flashing: probe-rs on real hardware.
pub trait Flasher {
    /// The debug probes attached.
    fn list_probes(&mut self) -> Vec<ProbeDescription>;
    /// Open `probe` and attach to the STM32F411 through it (halting the core).
    fn attach(&mut self, probe: &ProbeDescription) -> Result<(), ProbeError>;
    /// Erase what the image needs and write it, reporting progress.
    fn program(
        &mut self,
        image: &FirmwareImage,
        progress: &mut dyn FnMut(FlashProgress),
    ) -> Result<(), ProbeError>;
    /// Read the flash back and compare it with the image (Err: where it differs or why it
    /// could not be read).
    fn verify(
        &mut self,
        image: &FirmwareImage,
        progress: &mut dyn FnMut(FlashProgress),
    ) -> Result<(), ProbeError>;
    /// Reset the chip and let it run the new firmware; the probe is let go.
    fn reset(&mut self) -> Result<(), ProbeError>;
}

/// Why a step on the probe's side failed, in the probe's words ([`FlashError`] says what
/// to do about it).
#[derive(Debug, thiserror::Error)]
pub enum ProbeError {
    /// No probe is attached (attach first; a reset lets it go).
    #[error("no probe is attached")]
    NotAttached,
    /// The probe chosen went away since it was listed.
    #[error("{0} is no longer attached")]
    Gone(ProbeDescription),
    /// The probe could not be opened.
    #[error("cannot open the probe: {0}")]
    Open(String),
    /// The flash loader refused a segment of the image.
    #[error("segment {index} at {address:#010x}: {detail}")]
    Segment {
        /// The segment's index in the image.
        index: usize,
        /// Its load address.
        address: u32,
        /// The loader's words.
        detail: String,
    },
    /// Verify asked for before anything was programmed.
    #[error("nothing was programmed")]
    NothingProgrammed,
    /// The probe's (or the flash algorithm's) own error, in its words.
    #[error("{0}")]
    Probe(String),
}

/// What probe-rs looks for, for the "no probe" message: the probe kinds of this build and
/// the USB ids of the common ones (the STM32F411 boards' usual ST-Link clones, CMSIS-DAP).
pub(crate) const PROBES_LOOKED_FOR: &str = "ST-Link V2/V2-1/V3 (USB 0483:3748, 0483:374b, 0483:374a, 0483:3742, 0483:3752, 0483:374e, 0483:374f, 0483:3753, 0483:3754, 0483:3757), \
CMSIS-DAP v2 (any USB device with a CMSIS-DAP interface, e.g. a Raspberry Pi debugprobe 2e8a:000c; CMSIS-DAP v1 over HID is not in this build), \
SEGGER J-Link (USB 1366:*), FTDI MPSSE (USB 0403:*), WCH-Link, ESP USB-JTAG, Black Magic Probe, Glasgow";

/// The chip `gonio flash` attaches to: the board's (firmware/board/.cargo/config.toml).
pub(crate) const CHIP: &str = "STM32F411CEUx";

/// Why flashing failed. Each says what to do.
#[derive(Debug, thiserror::Error)]
pub enum FlashError {
    /// No probe attached.
    #[error(
        "no debug probe found. Looked for: {PROBES_LOOKED_FOR}. Connect the probe to USB and its SWD wires (SWDIO, SWCLK, GND; 3V3 if the board is not powered otherwise) to the board; on Linux, the probe's udev rules must let you open it (https://probe.rs/docs/getting-started/probe-setup/)"
    )]
    NoProbe,
    /// Several probes and none chosen, or the chosen one is not there.
    #[error("{}; choose one with --probe N:\n{}", if let Some(n) = chosen { format!("there is no probe {n}") } else { format!("{} debug probes are attached", probes.len()) }, list_probes(probes))]
    ChooseProbe {
        /// The probes found.
        probes: Vec<ProbeDescription>,
        /// The index asked for, if one was.
        chosen: Option<usize>,
    },
    /// The chip could not be reached through the probe.
    #[error(
        "cannot attach to the {CHIP} through {probe}: {detail}. Check the SWD wiring and the board's power; a board whose firmware disabled SWD needs BOOT0 high during the reset"
    )]
    Attach {
        /// The probe.
        probe: ProbeDescription,
        /// The probe's words.
        detail: ProbeError,
    },
    /// Erasing or writing failed.
    #[error(
        "writing the flash failed: {0}. The instrument holds no usable firmware now: flash again"
    )]
    Program(ProbeError),
    /// The flash does not hold the image after writing.
    #[error(
        "verify after writing failed: {0}. The instrument's flash does not hold the image: flash again, and do not use the instrument until a verify passes"
    )]
    Verify(ProbeError),
    /// The chip could not be reset.
    #[error(
        "the image is written and verified, but the reset failed: {0}. Press the board's reset button (or unplug it) to start it"
    )]
    Reset(ProbeError),
    /// The instrument did not enumerate after the reset.
    #[error(
        "the image is written and verified, but the instrument did not appear on USB ({:04x}:{:04x}) within {:.0} s after the reset{}. Is the board's USB cable plugged into this computer?",
        protocol::USB_VID, protocol::USB_PID, waited.as_secs_f64(), last_problem.as_ref().map(|p| format!(" (last: {p})")).unwrap_or_default()
    )]
    NotEnumerated {
        /// How long it was waited for.
        waited: Duration,
        /// The last problem finding it, if any.
        last_problem: Option<String>,
    },
    /// It enumerated but the handshake failed.
    #[error(
        "the image is written and verified, and the instrument appeared at {port}, but the handshake failed: {source}"
    )]
    Handshake {
        /// Where it appeared.
        port: String,
        /// The link's error.
        source: LinkError,
    },
    /// The instrument runs another firmware than the one flashed.
    #[error(
        "the instrument at {port} reports firmware {running}, not {flashed}, the version just flashed: the new image did not start; flash again"
    )]
    OtherFirmwareRunning {
        /// Where it is.
        port: String,
        /// What it reports.
        running: String,
        /// What was flashed.
        flashed: String,
    },
}

fn list_probes(probes: &[ProbeDescription]) -> String {
    probes
        .iter()
        .enumerate()
        .map(|(i, p)| format!("  {i}: {p}"))
        .collect::<Vec<_>>()
        .join("\n")
}

/// How to flash.
#[derive(Clone, Copy, Debug)]
pub struct FlashOptions {
    /// Which probe (an index into [`Flasher::list_probes`]), when several are attached.
    pub probe: Option<usize>,
    /// How long to wait for the instrument to enumerate after the reset.
    pub enumerate_timeout: Duration,
    /// How often to look for it meanwhile.
    pub poll_every: Duration,
    /// How long after the reset before the first look: the old firmware's USB port takes a
    /// moment to go away, and must not be mistaken for the new one.
    pub first_look_after: Duration,
}

impl Default for FlashOptions {
    fn default() -> Self {
        FlashOptions {
            probe: None,
            enumerate_timeout: Duration::from_secs(10),
            poll_every: Duration::from_millis(100),
            first_look_after: Duration::from_millis(500),
        }
    }
}

/// What a flash did.
#[derive(Clone, Debug)]
pub struct Flashed {
    /// The probe it went through.
    pub probe: ProbeDescription,
    /// Where the instrument appeared after the reset.
    pub port: String,
    /// Its handshake.
    pub device: DeviceInfo,
}

/// The probe to use: the only one, or the one chosen.
pub(crate) fn choose_probe(
    probes: Vec<ProbeDescription>,
    chosen: Option<usize>,
) -> Result<ProbeDescription, FlashError> {
    match (probes.len(), chosen) {
        (0, _) => Err(FlashError::NoProbe),
        (1, None) => Ok(probes.into_iter().next().expect("one probe")),
        (_, Some(n)) if n < probes.len() => Ok(probes.into_iter().nth(n).expect("index checked")),
        (_, chosen) => Err(FlashError::ChooseProbe { probes, chosen }),
    }
}

/// Flash `image` through `flasher` and wait for the instrument: `find_instrument` is asked
/// until it returns the instrument's link (`Ok(None)`: not there yet; `Err`: a problem
/// that may pass, such as a port that is not ready), at most `options.enumerate_timeout`
/// after the reset.
pub fn flash<F: Flasher + ?Sized, T: Transport>(
    flasher: &mut F,
    image: &FirmwareImage,
    options: FlashOptions,
    progress: &mut dyn FnMut(FlashProgress),
    find_instrument: &mut dyn FnMut() -> Result<Option<T>, String>,
) -> Result<Flashed, FlashError> {
    let probe = choose_probe(flasher.list_probes(), options.probe)?;
    flasher
        .attach(&probe)
        .map_err(|detail| FlashError::Attach {
            probe: probe.clone(),
            detail,
        })?;
    flasher
        .program(image, progress)
        .map_err(FlashError::Program)?;
    flasher
        .verify(image, progress)
        .map_err(FlashError::Verify)?;
    flasher.reset().map_err(FlashError::Reset)?;

    let started = Instant::now();
    std::thread::sleep(options.first_look_after.min(options.enumerate_timeout));
    let mut last_problem = None;
    let transport = loop {
        match find_instrument() {
            Ok(Some(transport)) => break transport,
            Ok(None) => {}
            Err(problem) => last_problem = Some(problem),
        }
        if started.elapsed() >= options.enumerate_timeout {
            return Err(FlashError::NotEnumerated {
                waited: started.elapsed(),
                last_problem,
            });
        }
        std::thread::sleep(options.poll_every);
    };
    let port = transport.name();
    let mut client = Client::new(transport, RetryPolicy::default());
    let device = client.hello().map_err(|source| FlashError::Handshake {
        port: port.clone(),
        source,
    })?;
    if device.firmware_version != image.info.firmware_version {
        return Err(FlashError::OtherFirmwareRunning {
            port,
            running: device.firmware_version.as_str().to_owned(),
            flashed: image.info.firmware_version.as_str().to_owned(),
        });
    }
    Ok(Flashed {
        probe,
        port,
        device,
    })
}
