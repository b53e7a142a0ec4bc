//! Is this file a firmware image `gonio flash` may write to the instrument? The checks run
//! before any probe is touched, on the bytes of the file alone (pure: no I/O).
//!
//! An image passes when it is a 32-bit little-endian ARM ELF executable whose every load
//! segment with contents lies in the STM32F411's flash by its physical (load) address, whose
//! vector table at the start of flash is sane (initial stack pointer in SRAM, reset vector a
//! Thumb address in flash), and which carries a `.gonio.info` section ([`FirmwareInfo`])
//! that is not itself loaded, naming a protocol version this host speaks and the board.
//! What passes is what is flashed: [`FirmwareImage::segments`] are the bytes handed to the
//! probe, so nothing unchecked reaches the chip.
//!
//! The ELF is read with the `object` crate (its low-level ELF reader); every offset and
//! size in the file is checked by it, so a truncated or garbled file is an error, not a
//! panic.
use object::elf;
use object::read::elf::{FileHeader, ProgramHeader, SectionHeader};
use object::{Endianness, FileKind};
use protocol::{F411_BOARD_NAME, FirmwareInfo, FirmwareInfoError, PROTOCOL_VERSION};

/// The STM32F411's flash: its first byte (where the vector table must be).
pub(crate) const FLASH_START: u32 = 0x0800_0000;
/// The STM32F411's flash, bytes (512 KiB on the F411CE and RE).
pub(crate) const FLASH_LEN: u32 = 512 * 1024;
/// The STM32F411's SRAM: its first byte.
pub(crate) const SRAM_START: u32 = 0x2000_0000;
/// The STM32F411's SRAM, bytes (128 KiB). An initial stack pointer may be the address just
/// past its end (a full-descending stack starts there).
pub(crate) const SRAM_LEN: u32 = 128 * 1024;
/// The section that says what the image is.
pub(crate) const INFO_SECTION: &str = ".gonio.info";

/// One load segment of the image: what is written where.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct LoadSegment {
    /// Its index in the ELF's program headers.
    pub index: usize,
    /// Where it goes: its physical (load) address, in flash.
    pub address: u32,
    /// Its bytes (the segment's file contents).
    pub data: Vec<u8>,
}

/// A firmware image that passed every check.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FirmwareImage {
    /// What `.gonio.info` says the image is.
    pub info: FirmwareInfo,
    /// The load segments with contents, in the order of the program headers.
    pub segments: Vec<LoadSegment>,
    /// The vector table's first word: the initial stack pointer.
    pub initial_sp: u32,
    /// The vector table's second word: the reset handler's address (odd: Thumb).
    pub reset_vector: u32,
}

impl FirmwareImage {
    /// Bytes written to flash.
    pub fn flash_bytes(&self) -> usize {
        self.segments.iter().map(|s| s.data.len()).sum()
    }

    /// What the image is, for people: version, protocol, board, flash use and segments.
    pub fn describe(&self) -> String {
        let mut text = format!(
            "firmware {} for board {}, protocol version {}\n{} bytes ({:.1} KiB) of flash in {} load segment{}; initial SP {:#010x}, reset vector {:#010x}\n",
            self.info.firmware_version,
            self.info.board,
            self.info.protocol_version,
            self.flash_bytes(),
            self.flash_bytes() as f64 / 1024.0,
            self.segments.len(),
            if self.segments.len() == 1 { "" } else { "s" },
            self.initial_sp,
            self.reset_vector
        );
        for s in &self.segments {
            let end = u64::from(s.address) + s.data.len() as u64;
            text.push_str(&format!(
                "  segment {}: {:#010x}..{:#010x}, {} bytes\n",
                s.index,
                s.address,
                end,
                s.data.len()
            ));
        }
        text
    }

    /// Check an image (the whole file's bytes) and take out what is to be flashed.
    pub fn check(bytes: &[u8]) -> Result<FirmwareImage, ImageError> {
        let header = elf_header(bytes)?;
        let endian = Endianness::Little;
        let segments = load_segments(header, endian, bytes)?;
        let (initial_sp, reset_vector) = vector_table(&segments)?;
        let info = info_section(header, endian, bytes)?;
        if info.protocol_version != PROTOCOL_VERSION {
            return Err(ImageError::ProtocolVersion {
                image: info.protocol_version,
                host: PROTOCOL_VERSION,
            });
        }
        if info.board.as_str() != F411_BOARD_NAME {
            return Err(ImageError::WrongBoard {
                board: info.board.as_str().to_owned(),
            });
        }
        Ok(FirmwareImage {
            info,
            segments,
            initial_sp,
            reset_vector,
        })
    }
}

/// Why an image may not be flashed. Each names what was wrong and where in the file.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum ImageError {
    /// Not an ELF file at all.
    #[error(
        "not an ELF file (it starts with {first_bytes}); gonio flash takes the board's ELF (firmware/board/target/thumbv7em-none-eabihf/release/gonio-board)"
    )]
    NotElf {
        /// Its first bytes, in hex.
        first_bytes: String,
    },
    /// A 64-bit ELF.
    #[error("a 64-bit ELF file; the STM32F411 (a Cortex-M4) takes a 32-bit ARM ELF")]
    Not32Bit,
    /// A big-endian ELF.
    #[error("a big-endian ELF file; the STM32F411 takes a little-endian ARM ELF")]
    BigEndian,
    /// The ELF's headers could not be read (a truncated or damaged file).
    #[error("a damaged ELF file: {what}: {detail}")]
    Malformed {
        /// What was being read.
        what: &'static str,
        /// The reader's words.
        detail: String,
    },
    /// Not for ARM.
    #[error(
        "an ELF file for machine {machine} (e_machine), not ARM ({}): not built for the STM32F411",
        elf::EM_ARM
    )]
    WrongMachine {
        /// Its `e_machine`.
        machine: u16,
    },
    /// Not an executable (an object file or a shared library).
    #[error(
        "an ELF file of type {e_type} (e_type), not an executable ({}): a linked firmware image is needed",
        elf::ET_EXEC
    )]
    NotExecutable {
        /// Its `e_type`.
        e_type: u16,
    },
    /// A load segment (partly) outside the flash.
    #[error(
        "load segment {index} (program header {index}) is to be written at {start:#010x}..{end:#010x} (physical address, {size} bytes), outside the STM32F411's flash ({:#010x}..{:#010x})",
        FLASH_START, u64::from(FLASH_START) + u64::from(FLASH_LEN)
    )]
    SegmentOutsideFlash {
        /// Program header index.
        index: usize,
        /// Its first byte.
        start: u64,
        /// One past its last byte.
        end: u64,
        /// Its file size.
        size: u64,
    },
    /// Two load segments write the same flash.
    #[error(
        "load segments {first} and {second} overlap in flash ({start:#010x}..{end:#010x}): the image is ambiguous"
    )]
    SegmentsOverlap {
        /// The earlier program header.
        first: usize,
        /// The later one.
        second: usize,
        /// The first byte both write.
        start: u32,
        /// One past the last.
        end: u32,
    },
    /// No load segment with contents.
    #[error("no load segment with contents: nothing to flash")]
    NothingToFlash,
    /// No segment holds the start of flash, where the vector table must be.
    #[error(
        "no vector table at the start of flash ({FLASH_START:#010x}): no load segment holds the 8 bytes there"
    )]
    NoVectorTable,
    /// The initial stack pointer is not in SRAM.
    #[error(
        "vector table at {FLASH_START:#010x}: the initial stack pointer {sp:#010x} is outside the SRAM ({SRAM_START:#010x}..={:#010x})",
        u64::from(SRAM_START) + u64::from(SRAM_LEN)
    )]
    StackPointerOutsideSram {
        /// The vector table's first word.
        sp: u32,
    },
    /// The initial stack pointer is not 8-byte aligned (AAPCS; cortex-m-rt asserts it).
    #[error(
        "vector table at {FLASH_START:#010x}: the initial stack pointer {sp:#010x} is not aligned to 8 bytes"
    )]
    StackPointerUnaligned {
        /// The vector table's first word.
        sp: u32,
    },
    /// The reset vector is even: not a Thumb address.
    #[error("vector table at {:#010x}: the reset vector {reset:#010x} is even, not a Thumb address (a Cortex-M runs Thumb code only; the core would fault at once)", FLASH_START + 4)]
    ResetVectorEven {
        /// The vector table's second word.
        reset: u32,
    },
    /// The reset vector points outside the flash.
    #[error(
        "vector table at {:#010x}: the reset vector {reset:#010x} points outside the flash ({FLASH_START:#010x}..{:#010x})",
        FLASH_START + 4, u64::from(FLASH_START) + u64::from(FLASH_LEN)
    )]
    ResetVectorOutsideFlash {
        /// The vector table's second word.
        reset: u32,
    },
    /// No `.gonio.info`.
    #[error(
        "no {INFO_SECTION} section: not a gonio firmware image (the board crate writes one saying its version, protocol and board)"
    )]
    MissingInfo,
    /// `.gonio.info` is an allocated section: it would take room in the target's memory.
    #[error(
        "section {INFO_SECTION} is allocated (SHF_ALLOC, at {address:#010x}): it must be an INFO section of the link script, not loaded into the target (firmware/board/gonio-info.x)"
    )]
    InfoAllocated {
        /// Its address.
        address: u32,
    },
    /// `.gonio.info` lies in a load segment: it would be flashed.
    #[error(
        "section {INFO_SECTION} (file bytes {start:#x}..{end:#x}) lies inside load segment {segment}: it would be written to flash"
    )]
    InfoInLoadSegment {
        /// Its first byte in the file.
        start: u64,
        /// One past its last byte.
        end: u64,
        /// The segment's program header index.
        segment: usize,
    },
    /// `.gonio.info` has no contents in the file (NOBITS).
    #[error("section {INFO_SECTION} has no contents in the file (SHT_NOBITS)")]
    InfoEmpty,
    /// `.gonio.info` is not a [`FirmwareInfo`].
    #[error("section {INFO_SECTION} is not gonio's firmware description: {0}")]
    InfoFormat(FirmwareInfoError),
    /// The image speaks a protocol this host does not.
    #[error(
        "the image speaks protocol version {image}, this host (gonio {}) speaks version {host}: {}",
        env!("CARGO_PKG_VERSION"),
        if image > host { "it needs a newer gonio; update gonio to the release that came with this firmware" } else { "it is older than this host; flash the firmware of this gonio release (gonio flash with no IMAGE, when built in) or one built from the same source" }
    )]
    ProtocolVersion {
        /// The image's.
        image: u16,
        /// This host's, [`PROTOCOL_VERSION`].
        host: u16,
    },
    /// Built for another board.
    #[error(
        "the image is built for board {board:?}, and gonio flash programs the {F411_BOARD_NAME} (STM32F411) board"
    )]
    WrongBoard {
        /// The image's board.
        board: String,
    },
}

fn malformed(what: &'static str) -> impl FnOnce(object::read::Error) -> ImageError {
    move |e| ImageError::Malformed {
        what,
        detail: e.to_string(),
    }
}

/// The ELF header, once it is known to be a 32-bit little-endian ARM executable.
fn elf_header(bytes: &[u8]) -> Result<&elf::FileHeader32<Endianness>, ImageError> {
    match FileKind::parse(bytes) {
        Ok(FileKind::Elf32) => {}
        Ok(FileKind::Elf64) => return Err(ImageError::Not32Bit),
        // FileKind knows only ELF here (object's "elf" feature alone); anything else is
        // not an ELF, as is a file too short to say.
        _ => {
            let first_bytes = if bytes.is_empty() {
                "nothing: the file is empty".to_string()
            } else {
                bytes
                    .iter()
                    .take(8)
                    .map(|b| format!("{b:02x}"))
                    .collect::<Vec<_>>()
                    .join(" ")
            };
            return Err(ImageError::NotElf { first_bytes });
        }
    }
    let header =
        elf::FileHeader32::<Endianness>::parse(bytes).map_err(malformed("the ELF header"))?;
    let endian = header
        .endian()
        .map_err(malformed("the ELF header's byte order"))?;
    if endian != Endianness::Little {
        return Err(ImageError::BigEndian);
    }
    if header.e_machine(endian) != elf::EM_ARM {
        return Err(ImageError::WrongMachine {
            machine: header.e_machine(endian),
        });
    }
    if header.e_type(endian) != elf::ET_EXEC {
        return Err(ImageError::NotExecutable {
            e_type: header.e_type(endian),
        });
    }
    Ok(header)
}

fn load_segments(
    header: &elf::FileHeader32<Endianness>,
    endian: Endianness,
    bytes: &[u8],
) -> Result<Vec<LoadSegment>, ImageError> {
    let flash = u64::from(FLASH_START)..u64::from(FLASH_START) + u64::from(FLASH_LEN);
    let mut segments = Vec::new();
    for (index, ph) in header
        .program_headers(endian, bytes)
        .map_err(malformed("the program headers"))?
        .iter()
        .enumerate()
    {
        if ph.p_type(endian) != elf::PT_LOAD || ph.p_filesz(endian) == 0 {
            continue;
        }
        let start = u64::from(ph.p_paddr(endian));
        let size = u64::from(ph.p_filesz(endian));
        let end = start + size;
        if start < flash.start || end > flash.end {
            return Err(ImageError::SegmentOutsideFlash {
                index,
                start,
                end,
                size,
            });
        }
        let data = ph.data(endian, bytes).map_err(|()| ImageError::Malformed {
            what: "a load segment's contents",
            detail: format!("program header {index} says {size} bytes at file offset {:#x}, past the end of the file ({} bytes)", ph.p_offset(endian), bytes.len()),
        })?;
        // In flash by the check above, so the address fits in 32 bits.
        segments.push(LoadSegment {
            index,
            address: start as u32,
            data: data.to_vec(),
        });
    }
    if segments.is_empty() {
        return Err(ImageError::NothingToFlash);
    }
    let end = |s: &LoadSegment| s.address + s.data.len() as u32; // in flash: no overflow
    for (i, a) in segments.iter().enumerate() {
        for b in &segments[i + 1..] {
            let (start, stop) = (a.address.max(b.address), end(a).min(end(b)));
            if start < stop {
                return Err(ImageError::SegmentsOverlap {
                    first: a.index,
                    second: b.index,
                    start,
                    end: stop,
                });
            }
        }
    }
    Ok(segments)
}

fn vector_table(segments: &[LoadSegment]) -> Result<(u32, u32), ImageError> {
    let word = |address: u32| -> Option<u32> {
        segments.iter().find_map(|s| {
            let offset = usize::try_from(address.checked_sub(s.address)?).ok()?;
            let bytes = s.data.get(offset..offset.checked_add(4)?)?;
            Some(u32::from_le_bytes(bytes.try_into().ok()?))
        })
    };
    let (Some(sp), Some(reset)) = (word(FLASH_START), word(FLASH_START + 4)) else {
        return Err(ImageError::NoVectorTable);
    };
    if !(SRAM_START..=SRAM_START + SRAM_LEN).contains(&sp) {
        return Err(ImageError::StackPointerOutsideSram { sp });
    }
    if sp % 8 != 0 {
        return Err(ImageError::StackPointerUnaligned { sp });
    }
    if reset % 2 == 0 {
        return Err(ImageError::ResetVectorEven { reset });
    }
    if !(FLASH_START..FLASH_START + FLASH_LEN).contains(&(reset & !1)) {
        return Err(ImageError::ResetVectorOutsideFlash { reset });
    }
    Ok((sp, reset))
}

fn info_section(
    header: &elf::FileHeader32<Endianness>,
    endian: Endianness,
    bytes: &[u8],
) -> Result<FirmwareInfo, ImageError> {
    let sections = header
        .sections(endian, bytes)
        .map_err(malformed("the section headers"))?;
    let Some((_, section)) = sections.section_by_name(endian, INFO_SECTION.as_bytes()) else {
        return Err(ImageError::MissingInfo);
    };
    if u64::from(section.sh_flags(endian)) & u64::from(elf::SHF_ALLOC) != 0 {
        return Err(ImageError::InfoAllocated {
            address: section.sh_addr(endian),
        });
    }
    let Some((start, size)) = section.file_range(endian) else {
        return Err(ImageError::InfoEmpty);
    };
    let end = start + size;
    for (index, ph) in header
        .program_headers(endian, bytes)
        .map_err(malformed("the program headers"))?
        .iter()
        .enumerate()
    {
        let (seg_start, seg_size) = ph.file_range(endian);
        if ph.p_type(endian) == elf::PT_LOAD
            && seg_size > 0
            && start < seg_start + seg_size
            && seg_start < end
        {
            return Err(ImageError::InfoInLoadSegment {
                start,
                end,
                segment: index,
            });
        }
    }
    let data = section
        .data(endian, bytes)
        .map_err(|e| ImageError::Malformed {
            what: "the .gonio.info section's contents",
            detail: format!(
                "{size} bytes at file offset {start:#x} in a file of {} bytes: {e}",
                bytes.len()
            ),
        })?;
    FirmwareInfo::decode(data).map_err(ImageError::InfoFormat)
}
