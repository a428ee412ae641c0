"""Output directories: one run at a time in each, a new one per run by default.

* :func:`take_out_dir`: a command's ``--out``, locked for this process before anything is
  written into it (``flock`` on the directory itself: nothing is added to it, and the kernel
  drops the lock when its owner dies, even by SIGKILL). A directory another live run holds is
  refused, ``--overwrite`` or not (:class:`OutDirBusyError`, naming the owner's pid); a non-empty
  one is refused without ``--overwrite``, which empties it first.
* :func:`new_run_dir`: with no ``--out``, a new directory per run, ``runs/<group>/<stamp>``
  (local time, ``2026-12-04T15-20-01``; ``-2``, ``-3`` ... after it when two runs start in the
  same second), taken the same way; ``runs/<group>/latest`` and ``runs/latest`` point to it
  once the command ends with it kept.
* :func:`release_out_dirs`: when the command ends. A start that was refused, failed or
  interrupted before any recording began (exit status 2, 3 or a signal's, and no meta.json
  under the directory) leaves nothing behind: what it wrote into a directory that was absent
  or empty when it took it is removed (so the corrected rerun is not refused as "not empty").
  Everything else is kept. Then the locks go.

Imports nothing of this project; both command lines (``hil``, ``virtual-robot``) use it.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import shutil
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

RUNS = Path("runs")  # where the per-run default directories go (relative to the working dir)
LATEST = "latest"
META = "meta.json"  # a recording's: its presence means a run began recording here
STAMP_FORMAT = "%Y-%m-%dT%H-%M-%S"
_TAKE_ATTEMPTS = 20  # a directory removed or replaced between open and lock: try again


class OutDirBusyError(ValueError):
    """The output directory belongs to another live run (a usage error: exit status 2)."""


@dataclass
class _Held:
    path: Path
    fd: int
    fresh: bool  # absent or empty when taken (or emptied by --overwrite): what is in it is ours
    created: bool  # made by this process
    group: Path | None  # runs/<group> of a per-run default directory, for its `latest` links
    made: list[Path] = field(default_factory=list)  # parents new_run_dir made, deepest first
    kept: Callable[[Path], None] | None = None  # told the directory once it is kept


_held: dict[tuple[int, int], _Held] = {}  # (st_dev, st_ino) -> the directory this process holds


def _owner_pid(st: os.stat_result) -> int | None:
    """The pid holding a flock on the file ``st`` describes (Linux /proc/locks), or None."""
    key = f"{os.major(st.st_dev):02x}:{os.minor(st.st_dev):02x}:{st.st_ino}"
    try:
        with open("/proc/locks") as f:
            for line in f:
                fields = line.split()
                # "1: FLOCK  ADVISORY  WRITE 12345 fe:00:2148628 0 EOF" (a waiter has "->")
                if "->" not in fields and len(fields) >= 6 and fields[5] == key:
                    return int(fields[4])
    except (OSError, ValueError):
        return None
    return None


def _lock(out: Path, label: str) -> tuple[int, bool, os.stat_result]:
    """``out`` created if absent and flock'ed (exclusive, not waiting): (fd, created, stat)."""
    for _ in range(_TAKE_ATTEMPTS):
        created = False
        try:
            out.mkdir(parents=True)
            created = True
        except FileExistsError:
            if not out.is_dir():
                raise ValueError(f"{label} {out}: exists and is not a directory") from None
        try:
            fd = os.open(out, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
        except FileNotFoundError:  # removed by the run that had it (its failed start): again
            continue
        st = os.fstat(fd)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            pid = _owner_pid(st)
            owner = f"pid {pid}" if pid is not None else "another process"
            raise OutDirBusyError(
                f"{label} {out}: in use by another run ({owner}); wait for it to end or choose "
                "another directory"
            ) from None
        try:
            now = os.stat(out)
        except FileNotFoundError:
            now = None
        if now is not None and (now.st_dev, now.st_ino) == (st.st_dev, st.st_ino):
            return fd, created, st
        os.close(fd)  # we locked a directory that was removed meanwhile: take the new one
    raise OutDirBusyError(f"{label} {out}: keeps being removed and recreated by another process")


def _empty(target: Path) -> None:
    for child in target.iterdir():
        if child.is_dir() and not child.is_symlink():
            shutil.rmtree(child)
        else:
            child.unlink()


def take_out_dir(
    out: str | Path,
    overwrite: bool,
    inputs: Sequence[str | Path | None] = (),
    *,
    label: str = "--out",
    group: Path | None = None,
) -> Path:
    """Lock ``out`` (created if absent) for this process until :func:`release_out_dirs`, then
    make sure it is empty: refuse a non-empty one (files of an earlier run would mix with this
    one's) unless ``overwrite``, which empties it first, and never one that holds one of the
    command's ``inputs``, the working or the home directory. A directory this process holds
    already is checked the same way, without a second lock."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"{label} {out}: exists and is not a directory")
    key = None
    with contextlib.suppress(OSError):
        st = os.stat(out)
        key = (st.st_dev, st.st_ino)
    held = _held.get(key) if key is not None else None
    if held is None:
        fd, created, st = _lock(out, label)
        key = (st.st_dev, st.st_ino)
        held = _held[key] = _Held(out, fd, fresh=True, created=created, group=group)
        taken_now = True
    else:
        created, taken_now = False, False
    try:
        if not created and any(out.iterdir()):
            _refuse_or_empty(out, overwrite, inputs, label)
    except BaseException:
        if taken_now:  # refused: what was there stays, and so does a directory we made
            held.fresh = held.created and not any(out.iterdir())
            _release(held, started=False)
            del _held[key]
        raise
    return out


def _refuse_or_empty(
    out: Path, overwrite: bool, inputs: Sequence[str | Path | None], label: str
) -> None:
    if not overwrite:
        raise ValueError(
            f"{label} {out}: directory is not empty (files of another run would mix with this "
            "one's); pass --overwrite to empty it, or choose another directory"
        )
    here = Path.cwd().resolve()
    target = out.resolve()
    for item in inputs:
        if item is not None and (
            Path(item).resolve() == target or target in Path(item).resolve().parents
        ):
            raise ValueError(f"{label} {out}: holds the input {item}; choose another directory")
    if target == here or target in here.parents or target == Path.home().resolve():
        raise ValueError(f"{label} {out}: refusing to empty the current or home directory")
    _empty(target)


def new_run_dir(
    group: str | Path, *, runs: Path = RUNS, kept: Callable[[Path], None] | None = None
) -> Path:
    """A new directory for one run, ``runs/<group>/<stamp>``, taken (:func:`take_out_dir`);
    ``kept(path)`` is called when the command ends with the directory kept (to say where the
    results are: a start that fails leaves no directory to name)."""
    base = runs / group
    stamp = time.strftime(STAMP_FORMAT)
    made = [p for p in (base, *base.parents) if not p.exists()]  # deepest first
    for n in range(1, 1000):
        out = base / (stamp if n == 1 else f"{stamp}-{n}")
        base.mkdir(parents=True, exist_ok=True)
        try:
            out.mkdir()
        except FileExistsError:
            continue
        taken = take_out_dir(out, False, label="run directory", group=base)
        for held in _held.values():
            if held.path == out:
                held.created = True  # made for this run: removed again if its start fails
                held.made = made  # and so are the empty parents made for it
                held.kept = kept
        return taken
    raise ValueError(f"{base}: no free run directory for {stamp} (1000 runs in one second?)")


def _point(link: Path, target: Path) -> None:
    """``link`` -> ``target`` (relative), replaced atomically."""
    tmp = link.with_name(f".{link.name}.{os.getpid()}.tmp")
    with contextlib.suppress(FileNotFoundError):
        tmp.unlink()
    os.symlink(os.path.relpath(target, link.parent), tmp)
    os.replace(tmp, link)


def _release(held: _Held, *, started: bool) -> None:
    """Drop what a start that never began recording left (see the module docstring), point the
    `latest` links at a kept per-run directory, unlock."""
    try:
        out = held.path
        if not started and held.fresh and out.is_dir() and not any(out.rglob(META)):
            _empty(out)
            if held.created:
                out.rmdir()
                for parent in held.made:  # deepest first; one another run uses stays
                    parent.rmdir()
        elif held.group is not None and out.is_dir():
            with contextlib.suppress(OSError):
                _point(held.group / LATEST, out)
                _point(held.group.parent / LATEST, out)
            if held.kept is not None:
                held.kept(out)
    except OSError:
        pass  # the clean-up is a courtesy: it never hides why the command ended
    finally:
        os.close(held.fd)


def release_out_dirs(status: int) -> None:
    """Release every directory this process took, as its command ends with exit ``status``:
    a start refused (2), not reached (3) or interrupted by a signal (128 + N) before any
    recording began leaves nothing behind; anything else is kept."""
    started = status not in (2, 3) and status < 128
    while _held:
        _, held = _held.popitem()
        _release(held, started=started)


def held_out_dirs() -> list[Path]:
    """The directories this process holds (for tests and messages)."""
    return [h.path for h in _held.values()]


__all__ = [
    "LATEST",
    "RUNS",
    "OutDirBusyError",
    "held_out_dirs",
    "new_run_dir",
    "release_out_dirs",
    "take_out_dir",
]
