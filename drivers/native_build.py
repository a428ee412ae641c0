"""Compiled kernels built once per source and toolchain into a user cache, shared by both ends:
the n-joint plant's RK4 step (:mod:`virtual_robot.compiled_step`, ``rk4_aba.cpp``) and the host
simulator's open-loop sub-step (:mod:`hil.model.compiled_openloop`, ``openloop_slide.c``).

:func:`build_cached` compiles a source with the command a caller gives into
:func:`cache_dir` (``$DDBENCH_KERNEL_CACHE``, else ``$XDG_CACHE_HOME/ddbench``, else
``~/.cache/ddbench``) under a name keyed by the hash of the source and the command (so a new
source, compiler or flag builds anew), under a file lock so concurrent processes build it once,
bounded in time; a failed compile is remembered beside the library (``.err``) so later runs do
not retry it. Every failure is :class:`KernelUnavailableError` with a one-line message: the
callers fall back to their Python step and say why.

Imports only the standard library.
"""

from __future__ import annotations

import fcntl
import hashlib
import logging
import os
import subprocess
import sys
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

__all__ = ["CACHE_ENV", "ERROR_CHARS", "KernelStatus", "KernelUnavailableError", "build_cached",
           "cache_dir", "cached_name", "kernel_status", "print_kernel_status"]  # fmt: skip

CACHE_ENV = "DDBENCH_KERNEL_CACHE"
ERROR_CHARS = 512


class KernelUnavailableError(RuntimeError):
    """The compiled kernel cannot be had; the message is one line saying why."""


@dataclass(frozen=True)
class KernelStatus:
    """Which step runs: ``compiled`` or ``python``, and why not compiled (one line)."""

    kernel: str
    reason: str | None = None
    library: str | None = None


_WARNED: set[str] = set()


def kernel_status(
    env: str, load: Callable[[], object], library: Callable[[], Path], what: str
) -> KernelStatus:
    """Which step runs as the environment variable ``env`` chooses: ``auto`` (default:
    compiled when ``load()`` succeeds), ``python`` (always the Python step), ``compiled``
    (ValueError, one line, when ``load()`` fails). In ``auto`` a failure warns once per
    process and reason, naming ``what`` ("compiled plant step unavailable: ...")."""
    choice = os.environ.get(env, "auto").strip().lower() or "auto"
    if choice not in ("auto", "python", "compiled"):
        raise ValueError(f"{env}={choice!r}: use auto, python or compiled")
    if choice == "python":
        return KernelStatus("python", f"{env}=python")
    try:
        load()
        return KernelStatus("compiled", library=str(library()))
    except KernelUnavailableError as exc:
        if choice == "compiled":
            raise ValueError(f"{env}=compiled: {exc}") from None
        if str(exc) not in _WARNED:  # once per process and reason, one line
            _WARNED.add(str(exc))
            logging.getLogger(__name__).warning("%s unavailable: %s", what, exc)
        return KernelStatus("python", str(exc))


def print_kernel_status(program: str, step: str, status: Callable[[], KernelStatus]) -> int:
    """A kernel module's ``main``: build (or find) it and print one line saying which
    ``step`` runs; exit 0 either way (the Python step is a working fallback), 2 on a bad
    choice or a required kernel missing (one line on stderr)."""
    try:
        current = status()
    except ValueError as exc:
        print(f"{program}: error: {exc}", file=sys.stderr)
        return 2
    if current.kernel == "compiled":
        print(f"{step}: compiled ({current.library})")
    else:
        print(f"{step}: python ({current.reason})")
    return 0


def cache_dir() -> Path:
    """Where compiled kernels are cached (see the module docstring)."""
    if os.environ.get(CACHE_ENV):
        return Path(os.environ[CACHE_ENV])
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "ddbench"


def cached_name(source: Path, key_parts: Iterable[str], suffix: str = ".so") -> Path:
    """The cache path of ``source`` built with ``key_parts`` (its command, versions...)."""
    key = hashlib.sha256(source.read_bytes())
    for part in key_parts:
        key.update(part.encode() + b"\0")
    return cache_dir() / f"{source.stem}-{key.hexdigest()[:16]}{suffix}"


def _first_error(stderr: str) -> str:
    lines = [line.strip() for line in stderr.splitlines() if line.strip()]
    picked = next((line for line in lines if "error" in line), lines[0] if lines else "")
    return picked[:ERROR_CHARS]


def _remembered(failed: Path) -> KernelUnavailableError:
    return KernelUnavailableError(f"{failed.read_text().strip()} (remembered in {failed})")


def build_cached(
    source: Path,
    target: Path,
    command: Callable[[Path], list[str]],
    timeout_s: float,
    what: str,
) -> Path:
    """``target`` (from :func:`cached_name`), compiled from ``source`` by ``command(output)``
    if not there yet; KernelUnavailableError (one line) if it cannot be. ``what`` names the
    build in the one warning line a build prints (e.g. "the compiled plant step ... (about
    a minute of CPU)")."""
    failed = target.with_suffix(".err")
    if target.exists():
        return target
    if failed.exists():
        raise _remembered(failed)
    target.parent.mkdir(parents=True, exist_ok=True)
    with open(target.with_suffix(".lock"), "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # another process may be building it: wait for it
        if target.exists():
            return target
        if failed.exists():
            raise _remembered(failed)
        partial = target.with_suffix(f".{os.getpid()}.tmp")
        argv = command(partial)
        logging.getLogger(__name__).warning("building %s once into %s", what, target.parent)
        try:
            done = subprocess.run(argv, capture_output=True, text=True, timeout=timeout_s)
        except subprocess.TimeoutExpired:
            partial.unlink(missing_ok=True)
            # not remembered: a loaded machine may finish it next time
            raise KernelUnavailableError(
                f"compiling {source.name} took over {timeout_s:g} s"
            ) from None
        except OSError as exc:
            raise KernelUnavailableError(f"{argv[0]}: {exc}") from None
        if done.returncode != 0:
            partial.unlink(missing_ok=True)
            message = f"{argv[0]} failed on {source.name}: {_first_error(done.stderr)}"
            failed.write_text(message + "\n")
            raise KernelUnavailableError(message)
        os.replace(partial, target)
    return target
