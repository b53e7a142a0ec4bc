//! The steps of `gonio flash` after the image's checks, with a recording fake probe (no
//! hardware here): the order of the calls, the progress reported, every failure as its own
//! error (no probe, several, attach, program, verify, no instrument after the reset, a
//! handshake that fails or reports another firmware), and the handshake after the reset
//! made with the simulated instrument through the host's own link code.
use crate::firmware_support;
use firmware_support::ElfSpec;
use host::instrument::firmware_image::FirmwareImage;
use host::instrument::flash::{
    FlashError, FlashOptions, FlashProgress, FlashStep, Flasher, ProbeDescription, ProbeError,
    flash,
};
use host::instrument::link::Transport;
use protocol::{F411_BOARD_NAME, PROTOCOL_VERSION};
use std::time::Duration;

/// Flash sector size of the fake chip (the F411's first sectors are 16 KiB; smaller here so
/// that the small test image spans several).
const SECTOR: u64 = 256;

/// A probe that records what it is asked and keeps what it was given to write, as a chip's
/// flash would: its verify compares that with the image.
#[derive(Default)]
struct RecordingProbe {
    probes: Vec<ProbeDescription>,
    calls: Vec<String>,
    /// The flash: (address, bytes) as written.
    flash: Vec<(u32, Vec<u8>)>,
    refuse_attach: bool,
    fail_program_after: Option<usize>,
    /// Damage this byte of the first segment as it is written (a flash that does not take it).
    corrupt_byte: Option<usize>,
    /// When it was reset.
    reset_at: Option<std::time::Instant>,
}

fn stlink(serial: &str) -> ProbeDescription {
    ProbeDescription {
        identifier: "STLink V2".into(),
        vendor_id: 0x0483,
        product_id: 0x3748,
        serial_number: Some(serial.into()),
    }
}

impl RecordingProbe {
    fn with_probes(probes: Vec<ProbeDescription>) -> RecordingProbe {
        RecordingProbe {
            probes,
            ..RecordingProbe::default()
        }
    }
}

impl Flasher for RecordingProbe {
    fn list_probes(&mut self) -> Vec<ProbeDescription> {
        self.calls.push("list".into());
        self.probes.clone()
    }

    fn attach(&mut self, probe: &ProbeDescription) -> Result<(), ProbeError> {
        self.calls.push(format!(
            "attach {}",
            probe.serial_number.as_deref().unwrap_or("-")
        ));
        if self.refuse_attach {
            Err(ProbeError::Probe(
                "the target does not answer on SWD".into(),
            ))
        } else {
            Ok(())
        }
    }

    fn program(
        &mut self,
        image: &FirmwareImage,
        progress: &mut dyn FnMut(FlashProgress),
    ) -> Result<(), ProbeError> {
        self.calls.push("program".into());
        let bytes = image.flash_bytes() as u64;
        let sectors = bytes.div_ceil(SECTOR);
        progress(FlashProgress::Started {
            step: FlashStep::Erase,
            total_bytes: Some(sectors * SECTOR),
        });
        for _ in 0..sectors {
            progress(FlashProgress::Advanced {
                step: FlashStep::Erase,
                bytes: SECTOR,
            });
        }
        progress(FlashProgress::Finished(FlashStep::Erase));
        progress(FlashProgress::Started {
            step: FlashStep::Program,
            total_bytes: Some(bytes),
        });
        let mut pages = 0;
        for segment in &image.segments {
            let mut data = segment.data.clone();
            if let (Some(at), true) = (self.corrupt_byte, self.flash.is_empty()) {
                data[at] ^= 0xff;
            }
            for chunk in data.chunks(SECTOR as usize) {
                if self.fail_program_after == Some(pages) {
                    progress(FlashProgress::Failed(FlashStep::Program));
                    return Err(ProbeError::Probe(format!(
                        "the flash algorithm reported an error at {:#010x}",
                        segment.address
                    )));
                }
                progress(FlashProgress::Advanced {
                    step: FlashStep::Program,
                    bytes: chunk.len() as u64,
                });
                pages += 1;
            }
            self.flash.push((segment.address, data));
        }
        progress(FlashProgress::Finished(FlashStep::Program));
        Ok(())
    }

    fn verify(
        &mut self,
        image: &FirmwareImage,
        progress: &mut dyn FnMut(FlashProgress),
    ) -> Result<(), ProbeError> {
        self.calls.push("verify".into());
        progress(FlashProgress::Started {
            step: FlashStep::Verify,
            total_bytes: Some(image.flash_bytes() as u64),
        });
        for (segment, (address, written)) in image.segments.iter().zip(&self.flash) {
            if let Some(at) = segment.data.iter().zip(written).position(|(a, b)| a != b) {
                progress(FlashProgress::Failed(FlashStep::Verify));
                return Err(ProbeError::Probe(format!(
                    "{:#010x} reads {:#04x}, the image has {:#04x}",
                    *address as usize + at,
                    written[at],
                    segment.data[at]
                )));
            }
            progress(FlashProgress::Advanced {
                step: FlashStep::Verify,
                bytes: written.len() as u64,
            });
        }
        progress(FlashProgress::Finished(FlashStep::Verify));
        Ok(())
    }

    fn reset(&mut self) -> Result<(), ProbeError> {
        self.calls.push("reset".into());
        self.reset_at = Some(std::time::Instant::now());
        Ok(())
    }
}

fn image() -> FirmwareImage {
    FirmwareImage::check(&ElfSpec::good().build()).expect("the good image")
}

fn simulator() -> hil_sim::SimInstrument {
    let port = hil_sim::scene::SamplePort::new(std::sync::Arc::new(|_: f64, _: f64| 0.5));
    hil_sim::SimInstrument::new(port, hil_sim::SimConfig::default())
}

fn quick() -> FlashOptions {
    FlashOptions {
        probe: None,
        enumerate_timeout: Duration::from_millis(400),
        poll_every: Duration::from_millis(5),
        first_look_after: Duration::from_millis(20),
    }
}

/// The instrument appears at the `appears_at`-th look (0: the first), and the looks counted.
fn appearing_after(
    appears_at: usize,
    looks: &mut usize,
) -> impl FnMut() -> Result<Option<hil_sim::SimInstrument>, String> + '_ {
    move || {
        *looks += 1;
        Ok((*looks > appears_at).then(simulator))
    }
}

/// Progress as one line per step: its name, the bytes announced, the bytes reported, and
/// whether it was started first and finished last.
fn check_progress(events: &[FlashProgress]) -> Vec<(FlashStep, u64)> {
    let mut steps = Vec::new();
    let mut open: Option<(FlashStep, Option<u64>, u64)> = None;
    for event in events {
        match *event {
            FlashProgress::Started { step, total_bytes } => {
                assert!(
                    open.is_none(),
                    "{step:?} started inside another step: {events:?}"
                );
                open = Some((step, total_bytes, 0));
            }
            FlashProgress::Advanced { step, bytes } => {
                let (current, _, done) = open.as_mut().expect("progress outside a step");
                assert_eq!(*current, step);
                *done += bytes;
            }
            FlashProgress::Finished(step) => {
                let (current, total, done) =
                    open.take().expect("a step finished that never started");
                assert_eq!(current, step);
                assert_eq!(
                    total,
                    Some(done),
                    "{step:?}: announced and reported bytes differ"
                );
                steps.push((step, done));
            }
            FlashProgress::Failed(step) => panic!("{step:?} failed: {events:?}"),
        }
    }
    assert!(open.is_none(), "a step never finished");
    steps
}

#[test]
fn a_flash_programs_verifies_resets_then_handshakes_with_the_new_firmware() {
    let image = image();
    for appears_at in [0, 1, 4, 20] {
        let mut probe = RecordingProbe::with_probes(vec![stlink("A1")]);
        let mut events = Vec::new();
        let mut looks = 0;
        let flashed = flash(
            &mut probe,
            &image,
            quick(),
            &mut |p| events.push(p),
            &mut appearing_after(appears_at, &mut looks),
        )
        .expect("flashed");
        assert_eq!(
            probe.calls,
            ["list", "attach A1", "program", "verify", "reset"]
        );
        assert_eq!(
            looks,
            appears_at + 1,
            "looked for the instrument {looks} times"
        );
        let bytes = image.flash_bytes() as u64;
        assert_eq!(
            check_progress(&events),
            [
                (FlashStep::Erase, bytes.div_ceil(SECTOR) * SECTOR),
                (FlashStep::Program, bytes),
                (FlashStep::Verify, bytes)
            ]
        );
        // What reached the flash is the image's segments, where they belong.
        assert_eq!(
            probe.flash,
            image
                .segments
                .iter()
                .map(|s| (s.address, s.data.clone()))
                .collect::<Vec<_>>()
        );
        assert_eq!(
            flashed.device.firmware_version.as_str(),
            firmware::FIRMWARE_VERSION
        );
        assert_eq!(flashed.device.protocol_version, PROTOCOL_VERSION);
        assert_eq!(flashed.probe, stlink("A1"));
        assert_eq!(flashed.port, simulator().name());
    }
}

#[test]
fn the_old_firmware_s_port_is_given_time_to_go_before_the_first_look() {
    let mut probe = RecordingProbe::with_probes(vec![stlink("A1")]);
    let mut first_look = None;
    let mut find = || {
        first_look.get_or_insert_with(std::time::Instant::now);
        Ok(Some(simulator()))
    };
    let options = FlashOptions {
        first_look_after: Duration::from_millis(150),
        ..quick()
    };
    flash(&mut probe, &image(), options, &mut |_| {}, &mut find).expect("flashed");
    let waited = first_look.unwrap() - probe.reset_at.unwrap();
    assert!(
        waited >= Duration::from_millis(150),
        "looked {waited:?} after the reset"
    );
}

#[test]
fn a_verify_that_finds_other_bytes_fails_and_nothing_is_reset() {
    let image = image();
    for at in [0, 7, 1000] {
        let mut probe = RecordingProbe {
            corrupt_byte: Some(at),
            ..RecordingProbe::with_probes(vec![stlink("A1")])
        };
        let mut looks = 0;
        let error = flash(
            &mut probe,
            &image,
            quick(),
            &mut |_| {},
            &mut appearing_after(0, &mut looks),
        )
        .unwrap_err();
        assert!(matches!(error, FlashError::Verify(_)), "{error:?}");
        let text = error.to_string();
        assert!(
            text.contains("verify after writing failed")
                && text.contains(&format!("{:#010x} reads", 0x0800_0000 + at))
                && text.contains("flash again"),
            "{text}"
        );
        assert_eq!(probe.calls, ["list", "attach A1", "program", "verify"]);
        assert_eq!(
            looks, 0,
            "the instrument was looked for after a failed verify"
        );
    }
}

#[test]
fn no_probe_says_what_was_looked_for() {
    let mut probe = RecordingProbe::with_probes(Vec::new());
    let mut looks = 0;
    let error = flash(
        &mut probe,
        &image(),
        quick(),
        &mut |_| {},
        &mut appearing_after(0, &mut looks),
    )
    .unwrap_err();
    assert!(matches!(error, FlashError::NoProbe), "{error:?}");
    let text = error.to_string();
    for needle in [
        "no debug probe found",
        "ST-Link",
        "0483:3748",
        "CMSIS-DAP v2",
        "J-Link",
        "1366:",
        "SWDIO",
        "udev",
    ] {
        assert!(text.contains(needle), "no {needle:?} in: {text}");
    }
    assert_eq!(probe.calls, ["list"]);
}

#[test]
fn several_probes_are_listed_and_one_is_chosen_by_its_index() {
    let probes = vec![
        stlink("A1"),
        ProbeDescription {
            identifier: "CMSIS-DAP".into(),
            vendor_id: 0x2e8a,
            product_id: 0x000c,
            serial_number: None,
        },
    ];
    let mut probe = RecordingProbe::with_probes(probes.clone());
    let mut looks = 0;
    let text = flash(
        &mut probe,
        &image(),
        quick(),
        &mut |_| {},
        &mut appearing_after(0, &mut looks),
    )
    .unwrap_err()
    .to_string();
    assert!(
        text.contains("2 debug probes are attached")
            && text.contains("0: STLink V2 (USB 0483:3748, serial A1)")
            && text.contains("1: CMSIS-DAP (USB 2e8a:000c)")
            && text.contains("--probe N"),
        "{text}"
    );
    assert_eq!(probe.calls, ["list"]);

    let mut probe = RecordingProbe::with_probes(probes.clone());
    let error = flash(
        &mut probe,
        &image(),
        FlashOptions {
            probe: Some(2),
            ..quick()
        },
        &mut |_| {},
        &mut appearing_after(0, &mut looks),
    )
    .unwrap_err();
    assert!(
        error.to_string().starts_with("there is no probe 2"),
        "{error}"
    );

    let mut probe = RecordingProbe::with_probes(probes);
    flash(
        &mut probe,
        &image(),
        FlashOptions {
            probe: Some(1),
            ..quick()
        },
        &mut |_| {},
        &mut appearing_after(0, &mut looks),
    )
    .expect("flashed through probe 1");
    assert_eq!(probe.calls[1], "attach -");
}

#[test]
fn an_attach_or_a_program_that_fails_stops_there() {
    let mut probe = RecordingProbe {
        refuse_attach: true,
        ..RecordingProbe::with_probes(vec![stlink("A1")])
    };
    let mut looks = 0;
    let text = flash(
        &mut probe,
        &image(),
        quick(),
        &mut |_| {},
        &mut appearing_after(0, &mut looks),
    )
    .unwrap_err()
    .to_string();
    assert!(
        text.contains("cannot attach to the STM32F411CEUx through STLink V2")
            && text.contains("does not answer on SWD"),
        "{text}"
    );
    assert_eq!(probe.calls, ["list", "attach A1"]);

    for after in [0, 2, 4] {
        let mut probe = RecordingProbe {
            fail_program_after: Some(after),
            ..RecordingProbe::with_probes(vec![stlink("A1")])
        };
        let mut events = Vec::new();
        let error = flash(
            &mut probe,
            &image(),
            quick(),
            &mut |p| events.push(p),
            &mut appearing_after(0, &mut looks),
        )
        .unwrap_err();
        assert!(
            matches!(error, FlashError::Program(_)) && error.to_string().contains("flash again"),
            "{error}"
        );
        assert_eq!(probe.calls, ["list", "attach A1", "program"]);
        assert_eq!(
            events.last(),
            Some(&FlashProgress::Failed(FlashStep::Program))
        );
    }
    assert_eq!(looks, 0);
}

#[test]
fn an_instrument_that_never_appears_is_given_up_after_the_wait() {
    let mut probe = RecordingProbe::with_probes(vec![stlink("A1")]);
    let mut looks = 0;
    let mut never = || -> Result<Option<hil_sim::SimInstrument>, String> {
        looks += 1;
        if looks % 2 == 0 {
            Err("/dev/ttyACM0: Permission denied".into())
        } else {
            Ok(None)
        }
    };
    let started = std::time::Instant::now();
    let error = flash(&mut probe, &image(), quick(), &mut |_| {}, &mut never).unwrap_err();
    assert!(started.elapsed() >= quick().enumerate_timeout);
    let text = error.to_string();
    assert!(
        matches!(error, FlashError::NotEnumerated { .. }),
        "{error:?}"
    );
    assert!(
        text.contains("did not appear on USB (1209:0001)")
            && text.contains("Permission denied")
            && text.contains("written and verified"),
        "{text}"
    );
    assert_eq!(probe.calls.last().map(String::as_str), Some("reset"));
    assert!(looks > 2);
}

#[test]
fn an_instrument_running_other_firmware_after_the_reset_is_an_error() {
    // The image says 9.9.9; the simulator runs this source's firmware library.
    let image = FirmwareImage::check(
        &ElfSpec::with_info("9.9.9", PROTOCOL_VERSION, F411_BOARD_NAME).build(),
    )
    .unwrap();
    let mut probe = RecordingProbe::with_probes(vec![stlink("A1")]);
    let mut looks = 0;
    let text = flash(
        &mut probe,
        &image,
        quick(),
        &mut |_| {},
        &mut appearing_after(0, &mut looks),
    )
    .unwrap_err()
    .to_string();
    assert!(
        text.contains(&format!(
            "reports firmware {}, not 9.9.9",
            firmware::FIRMWARE_VERSION
        )) && text.contains("did not start"),
        "{text}"
    );
}

#[test]
fn a_handshake_that_fails_after_the_reset_says_where_the_instrument_is() {
    /// A port that takes requests and never answers, and says time passes quickly (the
    /// link's deadline is on the transport's clock), so the give-up is immediate.
    struct Mute(std::time::Duration);
    impl Transport for Mute {
        fn write_all(&mut self, _: &[u8]) -> std::io::Result<()> {
            Ok(())
        }
        fn read(&mut self, _: &mut [u8], timeout: Duration) -> std::io::Result<usize> {
            self.0 += timeout.max(Duration::from_millis(50));
            Ok(0)
        }
        fn pause(&mut self, duration: Duration) {
            self.0 += duration;
        }
        fn now(&self) -> Duration {
            self.0
        }
        fn name(&self) -> String {
            "/dev/ttyACM7".into()
        }
    }
    let mut probe = RecordingProbe::with_probes(vec![stlink("A1")]);
    let mut find = || Ok(Some(Mute(Duration::ZERO)));
    let text = flash(&mut probe, &image(), quick(), &mut |_| {}, &mut find)
        .unwrap_err()
        .to_string();
    assert!(
        text.contains("appeared at /dev/ttyACM7, but the handshake failed")
            && text.contains("nothing came back")
            && !text.contains("request"),
        "{text}"
    );
}
