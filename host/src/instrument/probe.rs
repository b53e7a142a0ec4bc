//! The real [`Flasher`]: probe-rs, through whatever debug probe is attached.
//!
//! The image's checked load segments are handed to probe-rs's flash loader as they are
//! (no file format of probe-rs's is used, so what is written is what
//! [`FirmwareImage::check`] passed); probe-rs picks the STM32F411's flash algorithm from its
//! built-in target description, erases the sectors the data covers, programs them, reads
//! them back, and resets the core.
//!
//! Not tested here: there is no probe on the machines that run the tests. The steps around
//! it are ([`super::flash`], with a recording fake).
use super::firmware_image::FirmwareImage;
use super::flash::{CHIP, FlashProgress, FlashStep, Flasher, ProbeDescription, ProbeError};
use probe_rs::flashing::{self, DownloadOptions, FlashLoader, ProgressEvent, ProgressOperation};
use probe_rs::probe::DebugProbeInfo;
use probe_rs::probe::list::Lister;
use probe_rs::{Permissions, Session};

/// probe-rs, and what it has open.
#[derive(Default)]
pub struct ProbeRsFlasher {
    /// What the last [`Flasher::list_probes`] found (probe-rs opens a probe from these).
    found: Vec<DebugProbeInfo>,
    session: Option<Session>,
    /// The image staged by [`Flasher::program`], for [`Flasher::verify`].
    loader: Option<FlashLoader>,
}

impl ProbeRsFlasher {
    /// No probe open yet.
    pub fn new() -> ProbeRsFlasher {
        ProbeRsFlasher::default()
    }

    fn session(&mut self) -> Result<&mut Session, ProbeError> {
        self.session.as_mut().ok_or(ProbeError::NotAttached)
    }
}

fn describe(info: &DebugProbeInfo) -> ProbeDescription {
    ProbeDescription {
        identifier: info.identifier.clone(),
        vendor_id: info.vendor_id,
        product_id: info.product_id,
        serial_number: info.serial_number.clone(),
    }
}

/// probe-rs's progress as gonio's ([`FlashStep`]). probe-rs announces each step's size
/// (one "progress bar" per flash algorithm) before any step starts; gonio's
/// [`FlashProgress::Started`] carries it when the step starts. The fill step (reading back
/// bytes to keep, unused here) is not reported.
struct Forward<'p> {
    /// Bytes announced per step: erase, program, verify.
    totals: [Option<u64>; 3],
    progress: &'p mut dyn FnMut(FlashProgress),
}

impl Forward<'_> {
    fn event(&mut self, event: ProgressEvent) {
        let step = |operation| match operation {
            ProgressOperation::Erase => Some(FlashStep::Erase),
            ProgressOperation::Program => Some(FlashStep::Program),
            ProgressOperation::Verify => Some(FlashStep::Verify),
            ProgressOperation::Fill => None,
        };
        let slot = |step: FlashStep| step as usize;
        match event {
            ProgressEvent::AddProgressBar { operation, total } => {
                if let Some(step) = step(operation) {
                    let announced = &mut self.totals[slot(step)];
                    *announced = Some(announced.unwrap_or(0) + total.unwrap_or(0));
                }
            }
            ProgressEvent::Started(operation) => {
                if let Some(step) = step(operation) {
                    (self.progress)(FlashProgress::Started {
                        step,
                        total_bytes: self.totals[slot(step)],
                    });
                }
            }
            ProgressEvent::Progress {
                operation, size, ..
            } => {
                if let Some(step) = step(operation) {
                    (self.progress)(FlashProgress::Advanced { step, bytes: size });
                }
            }
            ProgressEvent::Finished(operation) => {
                if let Some(step) = step(operation) {
                    (self.progress)(FlashProgress::Finished(step));
                }
            }
            ProgressEvent::Failed(operation) => {
                if let Some(step) = step(operation) {
                    (self.progress)(FlashProgress::Failed(step));
                }
            }
            _ => {}
        }
    }
}

impl Flasher for ProbeRsFlasher {
    fn list_probes(&mut self) -> Vec<ProbeDescription> {
        self.found = Lister::new().list_all();
        self.found.iter().map(describe).collect()
    }

    fn attach(&mut self, probe: &ProbeDescription) -> Result<(), ProbeError> {
        let info = self
            .found
            .iter()
            .find(|info| describe(info) == *probe)
            .ok_or_else(|| ProbeError::Gone(probe.clone()))?;
        let opened = info.open().map_err(|e| ProbeError::Open(e.to_string()))?;
        let session = opened
            .attach(CHIP, Permissions::default())
            .map_err(|e| ProbeError::Probe(e.to_string()))?;
        self.session = Some(session);
        Ok(())
    }

    fn program(
        &mut self,
        image: &FirmwareImage,
        progress: &mut dyn FnMut(FlashProgress),
    ) -> Result<(), ProbeError> {
        let session = self.session()?;
        let mut loader = session.target().flash_loader();
        for segment in &image.segments {
            loader
                .add_data(u64::from(segment.address), &segment.data)
                .map_err(|e| ProbeError::Segment {
                    index: segment.index,
                    address: segment.address,
                    detail: e.to_string(),
                })?;
        }
        let mut options = DownloadOptions::default();
        // Verified on its own afterwards (Flasher::verify), so that a failure says which.
        options.verify = false;
        let mut forward = Forward {
            totals: [None; 3],
            progress,
        };
        options.progress = flashing::FlashProgress::new(move |event| forward.event(event));
        loader
            .commit(session, options)
            .map_err(|e| ProbeError::Probe(e.to_string()))?;
        self.loader = Some(loader);
        Ok(())
    }

    fn verify(
        &mut self,
        _image: &FirmwareImage,
        progress: &mut dyn FnMut(FlashProgress),
    ) -> Result<(), ProbeError> {
        let loader = self.loader.take().ok_or(ProbeError::NothingProgrammed)?;
        let session = self.session()?;
        let mut forward = Forward {
            totals: [None; 3],
            progress,
        };
        let mut reporter = flashing::FlashProgress::new(move |event| forward.event(event));
        loader
            .verify(session, &mut reporter)
            .map_err(|e| ProbeError::Probe(e.to_string()))
    }

    fn reset(&mut self) -> Result<(), ProbeError> {
        let mut session = self.session.take().ok_or(ProbeError::NotAttached)?;
        session
            .core(0)
            .map_err(|e| ProbeError::Probe(e.to_string()))?
            .reset()
            .map_err(|e| ProbeError::Probe(e.to_string()))
        // The session is dropped here: the probe lets the core run.
    }
}
