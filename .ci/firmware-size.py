#!/usr/bin/env python3
"""Flash and static RAM use of a Cortex-M firmware ELF, checked against a budget.

usage: firmware-size.py ELF FLASH_BUDGET_BYTES RAM_BUDGET_BYTES [--forbid PATH]...

Reads the ELF32 section headers (no binutils needed):
- flash: every allocated section with contents (vector table, text, rodata, and the
  initial image of .data, which is copied to RAM at boot);
- static RAM: every allocated section placed in SRAM (0x2000_0000..0x4000_0000):
  .data, .bss, .uninit. The stack is not counted: it takes the RAM that is left.
- --forbid PATH: the ELF must not contain PATH (a directory of the machine that built it:
  its checkout's crates, its $CARGO_HOME's sources). Panic locations carry file names, and
  .ci/thumbv7em-cargo remaps them (and the debug info's) to machine-independent ones; an
  absolute path in the flashed bytes means a build that skipped the remapping, whose size
  depends on where it was built (about 2.4 KB of paths, once); one in the debug info only,
  a remapping that missed a crate. One build shows it, no second one elsewhere.
Exits 1 when either is over its budget or a forbidden path is in the image, 2 when the
file is not a 32-bit little-endian ELF.
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

    for sh_name, sh_type, sh_flags, sh_addr, sh_off, sh_size, *_ in headers:
        contents = data[sh_off:sh_off + sh_size] if sh_type != SHT_NOBITS else b""
        yield name(sh_name), sh_type, sh_flags, sh_addr, sh_size, contents


def main():
    args = sys.argv[1:]
    forbidden = []
    while "--forbid" in args:
        at = args.index("--forbid")
        if at + 1 >= len(args):
            sys.exit(__doc__)
        forbidden.append(args[at + 1])
        del args[at:at + 2]
    if len(args) != 3:
        sys.exit(__doc__)
    path, flash_budget, ram_budget = args[0], int(args[1]), int(args[2])
    flash = ram = 0
    image = []
    with open(path, "rb") as f:
        whole = f.read()
    print(f"{'section':<16}{'size':>9}  {'address':>10}  counts as")
    for name, sh_type, flags, addr, size, contents in sections(path):
        if not flags & SHF_ALLOC or size == 0:
            continue
        where = []
        if sh_type != SHT_NOBITS:
            flash += size
            image.append(contents)
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
    # Each forbidden directory with a trailing slash: the path of a file in it.
    image = b"\0".join(image)
    leaks = [p for p in forbidden if (p.rstrip("/") + "/").encode() in whole]
    for leak in leaks:
        needle = (leak.rstrip("/") + "/").encode()
        flashed = needle in image
        where = image if flashed else whole
        at = where.index(needle)
        end = where.find(b"\0", at, at + 200)
        example = where[at:end if end > 0 else at + 120].decode(errors="replace")
        if flashed:
            print(f"error: the image holds a path of the build machine, {leak!r} (e.g."
                  f" {example!r}): its size depends on where it was built; build it with"
                  " .ci/thumbv7em-cargo, which remaps the paths", file=sys.stderr)
        else:
            print(f"error: the ELF's debug info holds a path of the build machine, {leak!r}"
                  f" (e.g. {example!r}): .ci/thumbv7em-cargo's remapping missed it",
                  file=sys.stderr)
    if forbidden and not leaks:
        print(f"no build-machine path in the image (checked: {', '.join(forbidden)})")
    if not ok or leaks:
        sys.exit(1)


if __name__ == "__main__":
    main()
