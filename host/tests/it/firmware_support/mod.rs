//! Firmware images for the tests of `gonio flash`, built with the `object` crate's ELF
//! writer: a good image laid out as the board's link script lays it out (vector table and
//! code at the start of flash, `.data`'s initial image after it, `.gonio.info` outside every
//! load segment), and every way of getting it wrong as a change of [`ElfSpec`].
#![allow(dead_code)]
use object::elf;
use object::write::elf::{FileHeader, ProgramHeader, SectionHeader, Writer};
use protocol::{F411_BOARD_NAME, FirmwareInfo, PROTOCOL_VERSION};

/// A load segment to write.
#[derive(Clone, Debug)]
pub struct SegmentSpec {
    /// Physical (load) address.
    pub paddr: u64,
    /// Virtual (run) address.
    pub vaddr: u64,
    /// Its contents.
    pub data: Vec<u8>,
    /// Memory size beyond the file size (zero-filled, as .bss).
    pub extra_memsz: u64,
}

/// Where and how `.gonio.info` is written.
#[derive(Clone, Debug)]
pub struct InfoSpec {
    /// Its contents.
    pub bytes: Vec<u8>,
    /// SHF_ALLOC set (and an address in flash).
    pub alloc: bool,
    /// Its file bytes lie inside this load segment (it would be flashed).
    pub inside_segment: Option<usize>,
}

/// An image to build.
#[derive(Clone, Debug)]
pub struct ElfSpec {
    /// ELF64 instead of ELF32.
    pub is_64: bool,
    /// Big-endian.
    pub big_endian: bool,
    /// `e_machine`.
    pub machine: u16,
    /// `e_type`.
    pub e_type: u16,
    /// Load segments.
    pub segments: Vec<SegmentSpec>,
    /// `.gonio.info`, if any.
    pub info: Option<InfoSpec>,
}

/// Initial SP of the good image: the top of the board's stack (memory.x).
pub const GOOD_SP: u32 = 0x2001_A000;
/// Reset vector of the good image (Thumb).
pub const GOOD_RESET: u32 = 0x0800_0101;

/// A vector table and 1 KiB of "code" with `sp` and `reset` in its first two words.
pub fn text(sp: u32, reset: u32) -> Vec<u8> {
    let mut data = Vec::with_capacity(1024);
    data.extend_from_slice(&sp.to_le_bytes());
    data.extend_from_slice(&reset.to_le_bytes());
    data.extend((8..1024u32).map(|i| (i * 7 + 3) as u8));
    data
}

/// `.gonio.info` of the given fields.
pub fn info_bytes(firmware_version: &str, protocol_version: u16, board: &str) -> Vec<u8> {
    FirmwareInfo::encode(firmware_version, protocol_version, board).to_vec()
}

impl ElfSpec {
    /// The good image: what the board crate's build produces, in small.
    pub fn good() -> ElfSpec {
        ElfSpec {
            is_64: false,
            big_endian: false,
            machine: elf::EM_ARM,
            e_type: elf::ET_EXEC,
            segments: vec![
                SegmentSpec {
                    paddr: 0x0800_0000,
                    vaddr: 0x0800_0000,
                    data: text(GOOD_SP, GOOD_RESET),
                    extra_memsz: 0,
                },
                // .data: runs in RAM, loaded from flash.
                SegmentSpec {
                    paddr: 0x0800_0400,
                    vaddr: 0x2001_A000,
                    data: vec![0x5a; 64],
                    extra_memsz: 0,
                },
                // .bss: nothing in the file.
                SegmentSpec {
                    paddr: 0x2001_A040,
                    vaddr: 0x2001_A040,
                    data: Vec::new(),
                    extra_memsz: 512,
                },
            ],
            info: Some(InfoSpec {
                bytes: info_bytes(
                    firmware::FIRMWARE_VERSION,
                    PROTOCOL_VERSION,
                    F411_BOARD_NAME,
                ),
                alloc: false,
                inside_segment: None,
            }),
        }
    }

    /// The good image with the vector table's two words replaced.
    pub fn with_vectors(sp: u32, reset: u32) -> ElfSpec {
        let mut spec = ElfSpec::good();
        spec.segments[0].data = text(sp, reset);
        spec
    }

    /// The good image with `.gonio.info` of these fields.
    pub fn with_info(firmware_version: &str, protocol_version: u16, board: &str) -> ElfSpec {
        let mut spec = ElfSpec::good();
        spec.info.as_mut().unwrap().bytes = info_bytes(firmware_version, protocol_version, board);
        spec
    }

    /// The file's bytes.
    pub fn build(&self) -> Vec<u8> {
        let endian = if self.big_endian {
            object::Endianness::Big
        } else {
            object::Endianness::Little
        };
        let mut buffer = Vec::new();
        let mut w = Writer::new(endian, self.is_64, &mut buffer);
        w.reserve_file_header();
        w.reserve_program_headers(self.segments.len() as u32);
        let offsets: Vec<usize> = self
            .segments
            .iter()
            .map(|s| w.reserve(s.data.len(), 4))
            .collect();
        let info_offset = match &self.info {
            Some(InfoSpec {
                inside_segment: Some(i),
                ..
            }) => Some(offsets[*i]),
            Some(info) => Some(w.reserve(info.bytes.len(), 1)),
            None => None,
        };
        w.reserve_null_section_index();
        let text_name = w.add_section_name(b".text");
        w.reserve_section_index();
        let info_name = self.info.as_ref().map(|_| {
            let name = w.add_section_name(b".gonio.info");
            w.reserve_section_index();
            name
        });
        w.reserve_shstrtab_section_index();
        w.reserve_shstrtab();
        w.reserve_section_headers();

        let entry = u64::from(GOOD_RESET);
        w.write_file_header(&FileHeader {
            os_abi: 0,
            abi_version: 0,
            e_type: self.e_type,
            e_machine: self.machine,
            e_entry: entry,
            e_flags: 0x0500_0400,
        })
        .expect("file header");
        w.write_align_program_headers();
        for (s, &offset) in self.segments.iter().zip(&offsets) {
            w.write_program_header(&ProgramHeader {
                p_type: elf::PT_LOAD,
                p_flags: elf::PF_R | elf::PF_X,
                p_offset: offset as u64,
                p_vaddr: s.vaddr,
                p_paddr: s.paddr,
                p_filesz: s.data.len() as u64,
                p_memsz: s.data.len() as u64 + s.extra_memsz,
                p_align: 4,
            });
        }
        for (s, &offset) in self.segments.iter().zip(&offsets) {
            w.pad_until(offset);
            w.write(&s.data);
        }
        if let Some(
            info @ InfoSpec {
                inside_segment: None,
                ..
            },
        ) = &self.info
        {
            w.pad_until(info_offset.unwrap());
            w.write(&info.bytes);
        }
        w.write_shstrtab();
        w.write_null_section_header();
        w.write_section_header(&SectionHeader {
            name: Some(text_name),
            sh_type: elf::SHT_PROGBITS,
            sh_flags: u64::from(elf::SHF_ALLOC | elf::SHF_EXECINSTR),
            sh_addr: self.segments.first().map_or(0, |s| s.vaddr),
            sh_offset: offsets.first().map_or(0, |&o| o as u64),
            sh_size: self.segments.first().map_or(0, |s| s.data.len() as u64),
            sh_link: 0,
            sh_info: 0,
            sh_addralign: 4,
            sh_entsize: 0,
        });
        if let (Some(info), Some(name)) = (&self.info, info_name) {
            w.write_section_header(&SectionHeader {
                name: Some(name),
                sh_type: elf::SHT_PROGBITS,
                sh_flags: if info.alloc {
                    u64::from(elf::SHF_ALLOC)
                } else {
                    0
                },
                sh_addr: if info.alloc { 0x0800_0800 } else { 0 },
                sh_offset: info_offset.unwrap() as u64,
                sh_size: info.bytes.len() as u64,
                sh_link: 0,
                sh_info: 0,
                sh_addralign: 1,
                sh_entsize: 0,
            });
        }
        w.write_shstrtab_section_header();
        buffer
    }
}

/// Write `bytes` to a fresh file for a test and return its path.
pub fn write_image(dir: &std::path::Path, name: &str, bytes: &[u8]) -> std::path::PathBuf {
    std::fs::create_dir_all(dir).unwrap();
    let path = dir.join(name);
    std::fs::write(&path, bytes).unwrap();
    path
}
