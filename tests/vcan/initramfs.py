"""Build the tiny initramfs `make test-vcan` boots: static busybox, a few kernel modules, /init.

The guest kernel (Debian's linux-image, unpacked in a temporary directory, never installed) has
virtio, 9p and CAN as modules, so they must be loaded before the host's root can be mounted over
virtio-9p. This script finds the modules by name under an unpacked ``lib/modules/<version>``,
adds their dependencies (read from each module's ``.modinfo`` ``depends=`` entry, since the
unpacked package has no ``modules.dep`` and ``depmod`` may not be installed), and writes an
uncompressed "newc" cpio archive the kernel unpacks as its initramfs. ``/modules.order`` lists the
modules in load order (dependencies first) for ``/init`` to ``insmod``.

Standard library only: it runs with the host's python before the project's venv matters.

    python3 tests/vcan/initramfs.py --modules K/lib/modules/6.1.0-50-amd64 \\
        --busybox B/bin/busybox --init tests/vcan/init.sh --out /tmp/x/initramfs.cpio \\
        virtio_pci 9pnet_virtio 9p vcan can_raw
"""

from __future__ import annotations

import argparse
import re
import stat
import sys
from collections.abc import Iterable
from pathlib import Path

# Modules the guest needs: the PCI transport for virtio, 9p over it (the root file system and the
# results share), and the CAN stack with the virtual CAN drivers: vcan, and vxcan (a tunnel pair
# that carries the frames of sockets with loopback off, tests/vcan/test_vcan_mit.py).
GUEST_MODULES = ("virtio_pci", "9pnet_virtio", "9p", "vcan", "vxcan", "can_raw")

_DEPENDS = re.compile(rb"(?:^|\x00)depends=([^\x00]*)\x00")


def module_name(path: Path) -> str:
    """Kernel module name of a ``.ko`` file: the kernel treats ``-`` and ``_`` alike."""
    return path.name.removesuffix(".ko").replace("-", "_")


def module_depends(ko: Path) -> list[str]:
    """Names in the module's ``depends=`` modinfo entry (empty when it depends on nothing)."""
    match = _DEPENDS.search(ko.read_bytes())
    if match is None:
        return []
    return [module_name(Path(d.decode())) for d in match.group(1).split(b",") if d]


def index_modules(moddir: Path) -> dict[str, Path]:
    """Module name -> ``.ko`` path for every uncompressed module under ``moddir``."""
    return {module_name(p): p for p in sorted(moddir.rglob("*.ko"))}


def load_order(wanted: Iterable[str], index: dict[str, Path]) -> list[Path]:
    """The wanted modules and everything they depend on, each after its dependencies."""
    order: list[Path] = []
    done: set[str] = set()

    def visit(name: str, chain: tuple[str, ...]) -> None:
        name = name.replace("-", "_")
        if name in done:
            return
        if name in chain:
            raise ValueError(f"module dependency cycle: {' -> '.join((*chain, name))}")
        if name not in index:
            raise FileNotFoundError(f"kernel module {name} not found (is it built in, or .ko.xz?)")
        for dep in module_depends(index[name]):
            visit(dep, (*chain, name))
        done.add(name)
        order.append(index[name])

    for name in wanted:
        visit(name, ())
    return order


def _newc_entry(ino: int, name: str, mode: int, data: bytes = b"", rdev: tuple = (0, 0)) -> bytes:
    """One entry of a SVR4 "newc" cpio archive (the format the kernel unpacks as initramfs)."""
    encoded = name.encode() + b"\x00"
    fields = (ino, mode, 0, 0, 1, 0, len(data), 0, 0, rdev[0], rdev[1], len(encoded), 0)
    header = b"070701" + b"".join(f"{f:08X}".encode() for f in fields)
    pad_name = -(len(header) + len(encoded)) % 4
    return header + encoded + b"\x00" * pad_name + data + b"\x00" * (-len(data) % 4)


def write_initramfs(out: Path, busybox: Path, init_script: Path, modules: list[Path]) -> None:
    """Write the archive: /init, /bin/busybox, /lib/modules/*.ko, /modules.order, /dev/console."""
    entries: list[tuple[str, int, bytes, tuple]] = []
    for d in ("bin", "dev", "lib", "lib/modules", "proc", "sys", "root", "results", "tmp"):
        entries.append((d, stat.S_IFDIR | 0o755, b"", (0, 0)))
    # the kernel opens /dev/console for init's stdio before init can mount devtmpfs
    entries.append(("dev/console", stat.S_IFCHR | 0o600, b"", (5, 1)))
    entries.append(("bin/busybox", stat.S_IFREG | 0o755, busybox.read_bytes(), (0, 0)))
    entries.append(("bin/sh", stat.S_IFLNK | 0o777, b"busybox", (0, 0)))
    entries.append(("init", stat.S_IFREG | 0o755, init_script.read_bytes(), (0, 0)))
    for ko in modules:
        entries.append((f"lib/modules/{ko.name}", stat.S_IFREG | 0o644, ko.read_bytes(), (0, 0)))
    order = "".join(f"{ko.name}\n" for ko in modules).encode()
    entries.append(("modules.order", stat.S_IFREG | 0o644, order, (0, 0)))
    with open(out, "wb") as f:
        for ino, (name, mode, data, rdev) in enumerate(entries, start=1):
            f.write(_newc_entry(ino, name, mode, data, rdev))
        f.write(_newc_entry(0, "TRAILER!!!", 0))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--modules", type=Path, required=True, help="unpacked lib/modules/<version>")
    ap.add_argument("--busybox", type=Path, required=True, help="a statically linked busybox")
    ap.add_argument("--init", type=Path, required=True, help="the script to run as /init")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("names", nargs="*", default=list(GUEST_MODULES))
    args = ap.parse_args(argv)
    try:
        modules = load_order(args.names, index_modules(args.modules))
        write_initramfs(args.out, args.busybox, args.init, modules)
    except (OSError, ValueError) as exc:
        print(f"initramfs: {exc}", file=sys.stderr)
        return 1
    print(f"initramfs: {args.out} ({len(modules)} modules: {' '.join(m.stem for m in modules)})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
