//! The checks `gonio flash` makes of a firmware image before it touches a probe, on images
//! built here (tests/it/firmware_support): the good one passes and says what it is; each way
//! of getting it wrong gets its own error, in the library and through the binary
//! (`gonio flash --check`: exit 1, the reason on stderr, no panic); no file makes it panic.
use crate::cli_support;
use crate::firmware_support;
use cli_support::gonio;
use firmware_support::{ElfSpec, GOOD_RESET, GOOD_SP, InfoSpec, SegmentSpec, write_image};
use host::instrument::firmware_image::{FirmwareImage, ImageError};
use object::elf;
use proptest::prelude::*;
use protocol::{F411_BOARD_NAME, PROTOCOL_VERSION};

fn check(spec: &ElfSpec) -> Result<FirmwareImage, ImageError> {
    FirmwareImage::check(&spec.build())
}

#[test]
fn the_good_image_passes_and_is_described() {
    let image = check(&ElfSpec::good()).expect("the good image");
    assert_eq!(
        image.info.firmware_version.as_str(),
        firmware::FIRMWARE_VERSION
    );
    assert_eq!(image.info.protocol_version, PROTOCOL_VERSION);
    assert_eq!(image.info.board.as_str(), F411_BOARD_NAME);
    assert_eq!(
        (image.initial_sp, image.reset_vector),
        (GOOD_SP, GOOD_RESET)
    );
    // .bss (no file bytes) is not flashed; .data's initial image is, at its load address.
    assert_eq!(
        image
            .segments
            .iter()
            .map(|s| (s.index, s.address, s.data.len()))
            .collect::<Vec<_>>(),
        [(0, 0x0800_0000, 1024), (1, 0x0800_0400, 64)]
    );
    assert_eq!(image.flash_bytes(), 1088);
    let text = image.describe();
    for needle in [
        firmware::FIRMWARE_VERSION,
        F411_BOARD_NAME,
        &format!("protocol version {PROTOCOL_VERSION}"),
        "1088 bytes",
        "segment 1: 0x08000400..0x08000440",
    ] {
        assert!(text.contains(needle), "no {needle:?} in {text}");
    }
}

#[test]
fn the_stack_may_start_at_the_very_top_of_the_sram() {
    for sp in [0x2002_0000, 0x2000_0000, 0x2000_0008] {
        assert!(
            check(&ElfSpec::with_vectors(sp, GOOD_RESET)).is_ok(),
            "{sp:#x}"
        );
    }
    // The last byte of flash holds a Thumb instruction's start at most at its last halfword.
    assert!(check(&ElfSpec::with_vectors(GOOD_SP, 0x0807_fffd)).is_ok());
}

/// Every way of getting an image wrong, its error, and words its message must hold.
fn broken_images() -> Vec<(
    &'static str,
    ElfSpec,
    fn(&ImageError) -> bool,
    &'static [&'static str],
)> {
    let mut v: Vec<(
        &'static str,
        ElfSpec,
        fn(&ImageError) -> bool,
        &'static [&'static str],
    )> = Vec::new();
    let mut s = ElfSpec::good();
    s.is_64 = true;
    v.push((
        "elf64",
        s,
        |e| matches!(e, ImageError::Not32Bit),
        &["64-bit ELF", "32-bit ARM ELF"],
    ));
    let mut s = ElfSpec::good();
    s.big_endian = true;
    v.push((
        "big-endian",
        s,
        |e| matches!(e, ImageError::BigEndian),
        &["big-endian"],
    ));
    let mut s = ElfSpec::good();
    s.machine = elf::EM_386;
    v.push((
        "x86",
        s,
        |e| matches!(e, ImageError::WrongMachine { machine: 3 }),
        &["machine 3", "not ARM (40)"],
    ));
    let mut s = ElfSpec::good();
    s.e_type = elf::ET_REL;
    v.push((
        "object-file",
        s,
        |e| matches!(e, ImageError::NotExecutable { e_type: 1 }),
        &["type 1", "not an executable"],
    ));
    let mut s = ElfSpec::good();
    s.segments[1].paddr = 0x2001_A000;
    v.push((
        "data-in-ram",
        s,
        |e| {
            matches!(
                e,
                ImageError::SegmentOutsideFlash {
                    index: 1,
                    start: 0x2001_A000,
                    ..
                }
            )
        },
        &[
            "load segment 1",
            "0x2001a000..0x2001a040",
            "outside the STM32F411's flash (0x08000000..0x08080000)",
        ],
    ));
    let mut s = ElfSpec::good();
    s.segments[1].paddr = 0x0807_FFF0;
    v.push((
        "past-flash-end",
        s,
        |e| {
            matches!(
                e,
                ImageError::SegmentOutsideFlash {
                    index: 1,
                    end: 0x0808_0030,
                    ..
                }
            )
        },
        &["load segment 1", "0x0807fff0..0x08080030"],
    ));
    let mut s = ElfSpec::good();
    s.segments[0].paddr = 0x0800_4000;
    s.segments[0].vaddr = 0x0800_4000;
    s.segments[1].paddr = 0x0800_4400;
    v.push((
        "no-vector-table",
        s,
        |e| matches!(e, ImageError::NoVectorTable),
        &["no vector table at the start of flash (0x08000000)"],
    ));
    let mut s = ElfSpec::good();
    s.segments[1].paddr = 0x0800_03f0;
    v.push((
        "overlap",
        s,
        |e| {
            matches!(
                e,
                ImageError::SegmentsOverlap {
                    first: 0,
                    second: 1,
                    start: 0x0800_03f0,
                    end: 0x0800_0400
                }
            )
        },
        &["load segments 0 and 1 overlap", "0x080003f0..0x08000400"],
    ));
    let mut s = ElfSpec::good();
    s.segments.truncate(0);
    v.push((
        "no-segments",
        s,
        |e| matches!(e, ImageError::NothingToFlash),
        &["nothing to flash"],
    ));
    v.push((
        "sp-above-sram",
        ElfSpec::with_vectors(0x2002_0008, GOOD_RESET),
        |e| matches!(e, ImageError::StackPointerOutsideSram { sp: 0x2002_0008 }),
        &["initial stack pointer 0x20020008 is outside the SRAM (0x20000000..=0x20020000)"],
    ));
    v.push((
        "sp-below-sram",
        ElfSpec::with_vectors(0x1fff_fff8, GOOD_RESET),
        |e| matches!(e, ImageError::StackPointerOutsideSram { sp: 0x1fff_fff8 }),
        &["initial stack pointer 0x1ffffff8"],
    ));
    v.push((
        "sp-unaligned",
        ElfSpec::with_vectors(0x2001_9ffc, GOOD_RESET),
        |e| matches!(e, ImageError::StackPointerUnaligned { sp: 0x2001_9ffc }),
        &["0x20019ffc is not aligned to 8 bytes"],
    ));
    v.push((
        "reset-even",
        ElfSpec::with_vectors(GOOD_SP, 0x0800_0100),
        |e| matches!(e, ImageError::ResetVectorEven { reset: 0x0800_0100 }),
        &["reset vector 0x08000100 is even", "Thumb"],
    ));
    v.push((
        "reset-in-ram",
        ElfSpec::with_vectors(GOOD_SP, 0x2000_0101),
        |e| {
            matches!(
                e,
                ImageError::ResetVectorOutsideFlash { reset: 0x2000_0101 }
            )
        },
        &["reset vector 0x20000101 points outside the flash"],
    ));
    v.push((
        "reset-past-flash",
        ElfSpec::with_vectors(GOOD_SP, 0x0808_0001),
        |e| {
            matches!(
                e,
                ImageError::ResetVectorOutsideFlash { reset: 0x0808_0001 }
            )
        },
        &["reset vector 0x08080001 points outside the flash"],
    ));
    let mut s = ElfSpec::good();
    s.info = None;
    v.push((
        "no-info",
        s,
        |e| matches!(e, ImageError::MissingInfo),
        &["no .gonio.info section", "not a gonio firmware image"],
    ));
    let mut s = ElfSpec::good();
    s.info.as_mut().unwrap().alloc = true;
    v.push((
        "info-allocated",
        s,
        |e| {
            matches!(
                e,
                ImageError::InfoAllocated {
                    address: 0x0800_0800
                }
            )
        },
        &[".gonio.info is allocated", "0x08000800", "INFO section"],
    ));
    let mut s = ElfSpec::good();
    s.info.as_mut().unwrap().inside_segment = Some(0);
    v.push((
        "info-flashed",
        s,
        |e| matches!(e, ImageError::InfoInLoadSegment { segment: 0, .. }),
        &[
            ".gonio.info",
            "inside load segment 0",
            "would be written to flash",
        ],
    ));
    let mut s = ElfSpec::good();
    s.info = Some(InfoSpec {
        bytes: b"a version string, not gonio's layout".to_vec(),
        alloc: false,
        inside_segment: None,
    });
    v.push((
        "info-garbled",
        s,
        |e| {
            matches!(
                e,
                ImageError::InfoFormat(protocol::FirmwareInfoError::Length(36))
            )
        },
        &[
            ".gonio.info is not gonio's firmware description",
            "36 bytes",
        ],
    ));
    v.push((
        "protocol-newer",
        ElfSpec::with_info(firmware::FIRMWARE_VERSION, PROTOCOL_VERSION + 1, F411_BOARD_NAME),
        |e| matches!(e, ImageError::ProtocolVersion { image, host } if *image == PROTOCOL_VERSION + 1 && *host == PROTOCOL_VERSION),
        &["needs a newer gonio"],
    ));
    v.push((
        "protocol-older",
        ElfSpec::with_info(firmware::FIRMWARE_VERSION, PROTOCOL_VERSION - 1, F411_BOARD_NAME),
        |e| matches!(e, ImageError::ProtocolVersion { image, host } if *image == PROTOCOL_VERSION - 1 && *host == PROTOCOL_VERSION),
        &["older than this host"],
    ));
    v.push((
        "other-board",
        ElfSpec::with_info(firmware::FIRMWARE_VERSION, PROTOCOL_VERSION, "gonio-rp2040"),
        |e| matches!(e, ImageError::WrongBoard { .. }),
        &["built for board \"gonio-rp2040\"", "gonio-f411"],
    ));
    v
}

#[test]
fn every_broken_image_gets_its_own_error() {
    let mut messages = std::collections::BTreeSet::new();
    for (name, spec, expected, needles) in broken_images() {
        let error = check(&spec).expect_err(name);
        assert!(expected(&error), "{name}: {error:?}");
        let text = error.to_string();
        for needle in needles {
            assert!(text.contains(needle), "{name}: no {needle:?} in: {text}");
        }
        messages.insert(text);
    }
    assert_eq!(
        messages.len(),
        broken_images().len(),
        "two broken images share a message"
    );
}

#[test]
fn the_protocol_versions_are_named_both() {
    for version in [PROTOCOL_VERSION - 1, PROTOCOL_VERSION + 1, 0, u16::MAX] {
        let text = check(&ElfSpec::with_info("0.1.0", version, F411_BOARD_NAME))
            .unwrap_err()
            .to_string();
        assert!(
            text.contains(&format!("protocol version {version}"))
                && text.contains(&format!("speaks version {PROTOCOL_VERSION}")),
            "{text}"
        );
    }
}

#[test]
fn what_is_not_an_elf_is_said_so() {
    for (bytes, shown) in [
        (&b""[..], "the file is empty"),
        (b"{\"schema\": 1}\n", "7b 22 73 63 68 65 6d 61"),
        (b"\x89PNG\r\n\x1a\n....", "89 50 4e 47"),
        (b"\x7fEL", "7f 45 4c"),
    ] {
        let error = FirmwareImage::check(bytes).unwrap_err();
        assert!(matches!(error, ImageError::NotElf { .. }), "{error:?}");
        assert!(error.to_string().contains(shown), "{error}");
    }
}

#[test]
fn every_truncation_of_the_good_image_is_refused() {
    let bytes = ElfSpec::good().build();
    for len in 0..bytes.len() {
        assert!(
            FirmwareImage::check(&bytes[..len]).is_err(),
            "{len} of {} bytes passed",
            bytes.len()
        );
    }
    // In the headers: a damaged ELF, said so.
    let error = FirmwareImage::check(&bytes[..40]).unwrap_err();
    assert!(matches!(error, ImageError::Malformed { .. }), "{error:?}");
    assert!(
        error.to_string().starts_with("a damaged ELF file: "),
        "{error}"
    );
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]
    /// Any bytes changed anywhere in a good image: an answer, never a panic.
    #[test]
    fn changed_bytes_never_panic(changes in proptest::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..8)) {
        let mut bytes = ElfSpec::good().build();
        for (at, value) in changes {
            let at = at.index(bytes.len());
            bytes[at] = value;
        }
        let _ = FirmwareImage::check(&bytes);
    }

    /// Load segments anywhere: in flash they pass, outside they are named.
    #[test]
    fn a_segment_passes_only_inside_the_flash(paddr in 0u64..=u64::from(u32::MAX), len in 1usize..4096) {
        let mut spec = ElfSpec::good();
        spec.segments[1] = SegmentSpec { paddr, vaddr: paddr, data: vec![1; len], extra_memsz: 0 };
        let inside = paddr >= 0x0800_0000 && paddr + len as u64 <= 0x0808_0000;
        // Segment 0 (the vector table and code) takes 0x0800_0000..0x0800_0400.
        let overlaps = paddr < 0x0800_0400 && paddr + len as u64 > 0x0800_0000;
        match check(&spec) {
            Ok(image) => prop_assert!(inside && !overlaps && image.segments[1].address as u64 == paddr),
            Err(ImageError::SegmentOutsideFlash { index: 1, .. }) => prop_assert!(!inside),
            Err(ImageError::SegmentsOverlap { first: 0, second: 1, .. }) => prop_assert!(inside && overlaps),
            Err(other) => prop_assert!(false, "{paddr:#x}+{len}: {other}"),
        }
    }
}

// Through the binary, as a user runs it.

/// A fresh folder of this test's own (tests run in parallel).
fn dir(test: &str) -> std::path::PathBuf {
    cli_support::temp_dir("flash-check", test)
}

#[test]
fn gonio_flash_check_describes_a_good_image_and_touches_no_probe() {
    let path = write_image(&dir("good"), "good.elf", &ElfSpec::good().build());
    let out = gonio(&["flash", "--check", path.to_str().unwrap()]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert_eq!(out.status.code(), Some(0), "{}", cli_support::stderr(&out));
    for needle in [
        firmware::FIRMWARE_VERSION,
        F411_BOARD_NAME,
        &format!("protocol version {PROTOCOL_VERSION}"),
        "1088 bytes",
        "2 load segments",
        "image checked",
    ] {
        assert!(stdout.contains(needle), "no {needle:?} in {stdout}");
    }
    assert!(
        !stdout.contains("probe"),
        "--check looked for a probe: {stdout}"
    );
}

#[test]
fn gonio_flash_check_refuses_every_broken_image_with_its_reason() {
    let dir = dir("broken");
    let mut files: Vec<(String, Vec<u8>, Vec<String>)> = broken_images()
        .into_iter()
        .map(|(name, spec, _, needles)| {
            (
                name.to_string(),
                spec.build(),
                needles.iter().map(|s| s.to_string()).collect(),
            )
        })
        .collect();
    let good = ElfSpec::good().build();
    files.push((
        "truncated".into(),
        good[..good.len() / 2].to_vec(),
        vec!["a damaged ELF file".into()],
    ));
    files.push((
        "text".into(),
        b"not firmware\n".to_vec(),
        vec!["not an ELF file".into()],
    ));
    for (name, bytes, needles) in files {
        let path = write_image(&dir, &format!("{name}.elf"), &bytes);
        let out = gonio(&["flash", "--check", path.to_str().unwrap()]);
        let message = cli_support::stderr(&out);
        assert_eq!(out.status.code(), Some(1), "{name}: {message}");
        assert!(!message.contains("panicked"), "{name}: {message}");
        assert!(
            message.contains(path.to_str().unwrap()),
            "{name}: the file is not named: {message}"
        );
        for needle in needles {
            assert!(
                message.contains(&needle),
                "{name}: no {needle:?} in: {message}"
            );
        }
    }
}

#[test]
fn gonio_flash_names_a_file_it_cannot_read() {
    let path = dir("missing").join("nothing-here.elf");
    let out = gonio(&["flash", "--check", path.to_str().unwrap()]);
    let message = cli_support::stderr(&out);
    assert_eq!(out.status.code(), Some(1), "{message}");
    assert!(
        message.contains("nothing-here.elf") && message.contains("cannot read"),
        "{message}"
    );
}

#[test]
fn gonio_flash_without_an_image_asks_for_one_when_none_is_built_in() {
    // A build with GONIO_FIRMWARE_IMAGE carries an image, and would flash it.
    if option_env!("GONIO_FIRMWARE_IMAGE").is_some_and(|p| !p.is_empty()) {
        eprintln!("skipped: this gonio has a firmware image built in");
        return;
    }
    for args in [&["flash"][..], &["flash", "--check"]] {
        let out = gonio(args);
        let message = cli_support::stderr(&out);
        assert_eq!(out.status.code(), Some(1), "{message}");
        assert!(
            message.contains("no firmware image built in") && message.contains("gonio flash IMAGE"),
            "{message}"
        );
    }
}

#[test]
fn gonio_flash_with_no_probe_attached_says_what_it_looked_for() {
    // probe-rs's own lister, as gonio flash uses it; with a probe attached this test would
    // flash a board, so it only runs where there is none (the test machines).
    use host::instrument::flash::Flasher;
    let probes = host::instrument::probe::ProbeRsFlasher::new().list_probes();
    if !probes.is_empty() {
        eprintln!("skipped: a debug probe is attached ({probes:?})");
        return;
    }
    let path = write_image(&dir("no-probe"), "good.elf", &ElfSpec::good().build());
    let out = gonio(&["flash", path.to_str().unwrap(), "--wait-s", "1"]);
    let message = cli_support::stderr(&out);
    assert_eq!(out.status.code(), Some(1), "{message}");
    for needle in [
        "no debug probe found",
        "ST-Link",
        "0483:3748",
        "CMSIS-DAP",
        "SWDIO",
    ] {
        assert!(message.contains(needle), "no {needle:?} in: {message}");
    }
    assert!(!message.contains("panicked"), "{message}");
}

#[test]
fn gonio_flash_refuses_a_wait_that_is_no_number_of_seconds() {
    let path = write_image(&dir("wait"), "good.elf", &ElfSpec::good().build());
    for bad in ["0", "-1", "inf", "NaN", "1e9"] {
        let option = format!("--wait-s={bad}");
        let out = gonio(&["flash", path.to_str().unwrap(), &option]);
        let message = cli_support::stderr(&out);
        assert_eq!(out.status.code(), Some(1), "{bad}: {message}");
        assert!(
            message.contains("--wait-s must be a number of seconds above 0 and at most 600"),
            "{bad}: {message}"
        );
    }
}
