"""tests/vcan/initramfs.py: module dependency order and the newc archive the guest kernel unpacks.

Runs on the host in `make test`; `make test-vcan` booting is the end-to-end check.
"""

from __future__ import annotations

import importlib.util
import os
import shutil
import stat
import subprocess
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent
_spec = importlib.util.spec_from_file_location("vcan_initramfs", HERE / "initramfs.py")
assert _spec is not None and _spec.loader is not None
initramfs = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(initramfs)


def fake_module(root: Path, rel: str, depends: str) -> Path:
    """A stand-in .ko: ELF bytes around a .modinfo section as the kernel build writes it."""
    path = root / rel
    path.parent.mkdir(parents=True, exist_ok=True)
    name = path.name.removesuffix(".ko").replace("-", "_")
    modinfo = f"license=GPL\x00depends={depends}\x00retpoline=Y\x00name={name}\x00"
    path.write_bytes(b"\x7fELF" + b"\x00" * 60 + modinfo.encode() + b"\x00" * 16)
    return path


@pytest.fixture
def moddir(tmp_path: Path) -> Path:
    root = tmp_path / "lib/modules/6.1.0-test"
    fake_module(root, "kernel/drivers/virtio/virtio.ko", "")
    fake_module(root, "kernel/drivers/virtio/virtio_ring.ko", "")
    fake_module(root, "kernel/drivers/virtio/virtio_pci.ko", "virtio_ring,virtio")
    fake_module(root, "kernel/net/9p/9pnet.ko", "")
    fake_module(root, "kernel/net/9p/9pnet_virtio.ko", "9pnet,virtio_ring,virtio")
    fake_module(root, "kernel/net/can/can.ko", "")
    fake_module(root, "kernel/net/can/can-raw.ko", "can")
    fake_module(root, "kernel/drivers/net/can/dev/can-dev.ko", "")
    fake_module(root, "kernel/drivers/net/can/vcan.ko", "can-dev")
    return root


def test_dependencies_come_first_once(moddir):
    order = initramfs.load_order(
        ["virtio_pci", "9pnet_virtio", "vcan", "can-raw"], initramfs.index_modules(moddir)
    )
    names = [initramfs.module_name(p) for p in order]
    assert sorted(names) == sorted(set(names))  # each once
    assert set(names) == {
        "virtio",
        "virtio_ring",
        "virtio_pci",
        "9pnet",
        "9pnet_virtio",
        "can",
        "can_raw",
        "can_dev",
        "vcan",
    }
    for module, deps in [
        ("virtio_pci", ["virtio", "virtio_ring"]),
        ("9pnet_virtio", ["9pnet", "virtio", "virtio_ring"]),
        ("can_raw", ["can"]),
        ("vcan", ["can_dev"]),
    ]:
        assert all(names.index(d) < names.index(module) for d in deps), (module, names)


def test_missing_module_and_cycle_are_errors(moddir):
    index = initramfs.index_modules(moddir)
    with pytest.raises(FileNotFoundError, match="kernel module nosuch not found"):
        initramfs.load_order(["nosuch"], index)
    fake_module(moddir, "kernel/a.ko", "b")
    fake_module(moddir, "kernel/b.ko", "a")
    with pytest.raises(ValueError, match="cycle: a -> b -> a"):
        initramfs.load_order(["a"], initramfs.index_modules(moddir))


def read_newc(data: bytes) -> dict[str, tuple[int, bytes, tuple[int, int]]]:
    """name -> (mode, contents, (rdevmajor, rdevminor)) of a newc archive, up to its trailer."""
    entries, pos = {}, 0
    while True:
        assert data[pos : pos + 6] == b"070701", pos
        fields = [int(data[pos + 6 + 8 * i : pos + 14 + 8 * i], 16) for i in range(13)]
        mode, size, rdev, namesize = fields[1], fields[6], (fields[9], fields[10]), fields[11]
        name = data[pos + 110 : pos + 110 + namesize - 1].decode()
        pos += 110 + namesize
        pos += -pos % 4
        if name == "TRAILER!!!":
            assert pos == len(data)
            return entries
        entries[name] = (mode, data[pos : pos + size], rdev)
        pos += size
        pos += -pos % 4


def test_archive_holds_init_busybox_console_and_ordered_modules(moddir, tmp_path):
    busybox = tmp_path / "busybox"
    busybox.write_bytes(b"\x7fELF busybox" * 3)  # odd length: padding is exercised
    order = initramfs.load_order(["vcan", "can_raw"], initramfs.index_modules(moddir))
    out = tmp_path / "initramfs.cpio"
    initramfs.write_initramfs(out, busybox, HERE / "init.sh", order)
    entries = read_newc(out.read_bytes())
    mode, init, _ = entries["init"]
    assert stat.S_ISREG(mode) and mode & 0o111 and init == (HERE / "init.sh").read_bytes()
    assert init.startswith(b"#!/bin/busybox sh\n")
    assert entries["bin/busybox"][1] == busybox.read_bytes()
    assert stat.S_ISLNK(entries["bin/sh"][0]) and entries["bin/sh"][1] == b"busybox"
    mode, _, rdev = entries["dev/console"]
    assert stat.S_ISCHR(mode) and rdev == (5, 1)
    listed = entries["modules.order"][1].decode().split()
    assert listed == [p.name for p in order] == ["can-dev.ko", "vcan.ko", "can.ko", "can-raw.ko"]
    for ko in order:
        assert entries[f"lib/modules/{ko.name}"][1] == ko.read_bytes()
    for d in ("dev", "proc", "sys", "root", "results", "lib/modules"):
        assert stat.S_ISDIR(entries[d][0])


def test_cli_reports_a_missing_module_in_one_line(moddir, tmp_path, capsys):
    busybox = tmp_path / "busybox"
    busybox.write_bytes(b"x")
    args = ["--modules", str(moddir), "--busybox", str(busybox), "--init", str(HERE / "init.sh")]
    assert initramfs.main([*args, "--out", str(tmp_path / "a.cpio"), "vcan"]) == 0
    assert initramfs.main([*args, "--out", str(tmp_path / "b.cpio"), "9p"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "kernel module 9p not found" in err


def test_run_script_skips_with_a_reason_and_status_0(tmp_path):
    """`make test-vcan` where it cannot run: exit 0 and one "skipped: <reason>" line."""
    tree = tmp_path / "checkout"
    (tree / "tests/vcan").mkdir(parents=True)
    shutil.copy(HERE / "run.sh", tree / "tests/vcan/run.sh")
    proc = subprocess.run(
        ["bash", str(tree / "tests/vcan/run.sh")],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
        env={**os.environ, "DDBENCH_VCAN_CACHE": str(tmp_path / "cache")},
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.splitlines()[-1].startswith("test-vcan: skipped: ")
    assert not (tmp_path / "cache").exists()  # nothing downloaded for a run that cannot happen
