#!/usr/bin/env python3
"""Flash and static RAM use of a Cortex-M firmware ELF, checked against a budget.

usage: firmware-size.py ELF FLASH_BUDGET_BYTES RAM_BUDGET_BYTES

Reads the ELF32 section headers (no binutils needed):
- flash: every allocated section with contents (vector table, text, rodata, and the
  initial image of .data, which is copied to RAM at boot);
- static RAM: every allocated section placed in SRAM (0x2000_0000..0x4000_0000):
  .data, .bss, .uninit. The stack is not counted: it takes the RAM that is left.
Exits 1 when either is over its budget, 2 when the file is not a 32-bit little-endian ELF.
"""
import struct
import sys

SHF_ALLOC = 0x2
SHT_NOBITS = 8
SRAM = range(0x2000_0000, 0x4000_0000)


def sections(path):
    with open(path, "rb") as f:
        data = f.read()
    if data[:4] != b"\x7fELF" or data[4] != 1 or data[5] != 1:
        sys.exit(f"error: {path} is not a 32-bit little-endian ELF file")
    shoff, = struct.unpack_from("<I", data, 0x20)
    shentsize, shnum, shstrndx = struct.unpack_from("<HHH", data, 0x2E)
    headers = [struct.unpack_from("<IIIIIIIIII", data, shoff + i * shentsize) for i in range(shnum)]
    strtab_off = headers[shstrndx][4]

    def name(offset):
        end = data.index(b"\0", strtab_off + offset)
        return data[strtab_off + offset:end].decode()

    for sh_name, sh_type, sh_flags, sh_addr, _off, sh_size, *_ in headers:
        yield name(sh_name), sh_type, sh_flags, sh_addr, sh_size


def main():
    if len(sys.argv) != 4:
        sys.exit(__doc__)
    path, flash_budget, ram_budget = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    flash = ram = 0
    print(f"{'section':<16}{'size':>9}  {'address':>10}  counts as")
    for name, sh_type, flags, addr, size in sections(path):
        if not flags & SHF_ALLOC or size == 0:
            continue
        where = []
        if sh_type != SHT_NOBITS:
            flash += size
            where.append("flash")
        if addr in SRAM:
            ram += size
            where.append("RAM")
        print(f"{name:<16}{size:>9}  0x{addr:08x}  {' + '.join(where)}")

    def line(what, used, budget):
        status = "OK" if used <= budget else "OVER BUDGET"
        print(f"{what}: {used} bytes ({used / 1024:.1f} KiB) of a {budget // 1024} KiB budget "
              f"({100 * used / budget:.0f} %): {status}")
        return used <= budget

    print()
    ok = line("flash (vector table + text + rodata + data)", flash, flash_budget)
    ok &= line("static RAM (data + bss + uninit)", ram, ram_budget)
    if not ok:
        print("error: the firmware is over its flash or RAM budget", file=sys.stderr)
        sys.exit(1)


if __name__ == "__main__":
    main()
