"""The open-loop validation's common sub-step compiled (issue 13's time on a 10 M-row recording):
``openloop_slide.c`` built once into the kernel cache (:mod:`drivers.native_build`), loaded
through ctypes, and :class:`Slider`, which :func:`hil.model.openloop_core.integrate_chunks`
runs (when :func:`compiled`) on the rows on which the stick mode does not change.

The C code is ``_rk4(_accelerations(...))`` of :mod:`hil.model.openloop_core` in each stick
mode, with the break-away test of its ``release`` (``_holding_torques``), for plain Coulomb
friction, no shaft torque and the identity torque path: the same operations in the same order,
compiled without fast-math, FMA contraction or builtins and calling the C library's sin and cos
as :mod:`math` does, so it gives the same bits as the Python step
(tests/test_openloop_compiled.py). It stops before any row inside which the mode changes (a
stuck joint breaks away, a sliding sticky joint's velocity changes sign); the Python integrator
takes that row (locating the event) and hands the rows after it back.

``DDBENCH_OPENLOOP_KERNEL`` chooses: ``auto`` (default: compiled when it builds), ``python``
(always the Python step), ``compiled`` (refuse to run without it). Built lazily on first use
or by ``make`` setup (``python -m hil.model.compiled_openloop``); without a C compiler the
Python step runs, with one warning line saying why.

Imports the standard library, numpy and :mod:`drivers.native_build`.
"""

from __future__ import annotations

import ctypes
import os
import shutil
import sys
from pathlib import Path

import numpy as np

from drivers import native_build
from drivers.native_build import (
    KernelStatus,
    KernelUnavailableError,
    build_cached,
    cache_dir,
    cached_name,
)

SOURCE = Path(__file__).with_name("openloop_slide.c")
KERNEL_ENV = "DDBENCH_OPENLOOP_KERNEL"
BUILD_TIMEOUT_S = 300.0  # a 2 s compile quiet; generous for a loaded machine
# Same rounding as Python's float arithmetic and math.sin/cos: no fast-math, no FMA
# contraction, no builtins (gcc fuses sin and cos of one argument into sincos otherwise).
CFLAGS = ("-O2", "-fPIC", "-shared", "-ffp-contract=off", "-fno-fast-math", "-fno-builtin")


def build_command(output: Path) -> list[str]:
    """The compiler call; KernelUnavailableError (one line) without a C compiler."""
    cc = os.environ.get("CC", "cc")
    if shutil.which(cc) is None:
        raise KernelUnavailableError(f"no C compiler {cc!r} on PATH")
    return [cc, *CFLAGS, str(SOURCE), "-o", str(output), "-lm"]


def library_path() -> Path:
    """Where the library of this source and toolchain is (or will be) cached."""
    return cached_name(SOURCE, (*build_command(Path("OUT")), sys.platform))


_LIBRARIES: dict[Path, ctypes.CDLL] = {}
_PATHS: dict[tuple[str | None, str | None, str], Path] = {}


def _library() -> Path:
    """:func:`library_path`, hashed once per toolchain and cache in a process (not once per
    simulation: the diagnosis runs many)."""
    toolchain = (os.environ.get("CC"), os.environ.get("PATH"), str(cache_dir()))
    if toolchain not in _PATHS:
        _PATHS[toolchain] = library_path()
    return _PATHS[toolchain]


def load() -> ctypes.CDLL:
    """The compiled library (built on first use), or KernelUnavailableError saying why not."""
    path = build_cached(
        SOURCE, _library(), build_command, BUILD_TIMEOUT_S, "the compiled open-loop step"
    )
    if path not in _LIBRARIES:
        try:
            lib = ctypes.CDLL(str(path))
        except OSError as exc:
            raise KernelUnavailableError(f"loading {path.name}: {exc}") from None
        fn = lib.ddb_openloop_slide
        fn.restype = ctypes.c_long
        # (p, perp, sticky1, sticky2, stuck1, stuck2, dir1, dir2, tau, stretch, rows, n_sub,
        # dt_seg, x, q_out, dq_out); the arrays by address
        fn.argtypes = [ctypes.c_void_p, *[ctypes.c_int] * 5, ctypes.c_double, ctypes.c_double,
                       ctypes.c_void_p, ctypes.c_void_p, ctypes.c_long, ctypes.c_int,
                       ctypes.c_double, *[ctypes.c_void_p] * 3]  # fmt: skip
        _LIBRARIES[path] = lib
    return _LIBRARIES[path]


def kernel_status() -> KernelStatus:
    """Which step the open-loop simulation runs, and why not compiled (one line); ValueError
    when the compiled one is required (``compiled``) and cannot be had."""
    return native_build.kernel_status(KERNEL_ENV, load, _library, "compiled open-loop step")


def compiled() -> bool:
    """Whether the simulation is to run the compiled step (:class:`Slider`): not when forced
    to Python, nor when it cannot be had (one warning line, see :func:`kernel_status`)."""
    return kernel_status().kernel == "compiled"


class Slider:
    """Rows of one simulation in one stick mode, run by the compiled step.

    ``rigid`` are the 11 numbers of :func:`hil.model.openloop_core._rigid`; ``torques`` (N, 2)
    and ``stretch`` (N − 1 period stretches, or None) those the integrator runs on; ``bands``
    the static bands (F⁺ joint 1, joint 2, F⁻ joint 1, joint 2) of its Coulomb friction.
    """

    def __init__(
        self,
        rigid: tuple[float, ...],
        torques: np.ndarray,
        stretch: np.ndarray | None,
        n_sub: int,
        dt_seg: float,
        sticky: tuple[bool, bool],
        bands: tuple[float, float, float, float],
    ) -> None:
        self._fn = load().ddb_openloop_slide
        # t1..t5 b1 b2 rot p2 p4 p5, the two levels (set per call), the four bands
        self._p = np.zeros(17)
        self._p[:11] = rigid
        self._p[13:] = bands
        p2, p4, p5 = rigid[8:11]
        self._perp = int(p2 != 0.0 or p4 != 0.0 or p5 != 0.0)
        self._tau = np.ascontiguousarray(torques, dtype=float)
        self._stretch = None if stretch is None else np.ascontiguousarray(stretch, dtype=float)
        self._n_sub, self._dt_seg = n_sub, float(dt_seg)
        self._sticky = (int(sticky[0]), int(sticky[1]))
        self._x = np.zeros(4)
        self._q_out = self._dq_out = np.empty((0, 2))

    def run(
        self,
        row: int,
        rows: int,
        state: tuple[float, float, float, float],
        stuck: tuple[bool, bool],
        levels: tuple[float, float],
        direction: tuple[float, float],
    ) -> tuple[int, tuple[float, float, float, float], np.ndarray, np.ndarray]:
        """From ``state`` at the start of recording row ``row``, up to ``rows`` rows in the
        mode ``stuck`` (the sliding joints' Coulomb ``levels`` of their ``direction``):
        (rows fully stepped m, the state after them, q and q̇ at the start of each of rows
        row..row + m − 1 (views of buffers the next call overwrites))."""
        self._p[11], self._p[12] = levels
        x = self._x
        x[:] = state
        if self._q_out.shape[0] < rows:  # kept from call to call: one chunk's rows
            self._q_out, self._dq_out = np.empty((rows, 2)), np.empty((rows, 2))
        q_out, dq_out = self._q_out, self._dq_out
        tau = self._tau.ctypes.data + row * self._tau.strides[0]
        stretch = None
        if self._stretch is not None:
            stretch = self._stretch.ctypes.data + row * self._stretch.strides[0]
        done = self._fn(
            self._p.ctypes.data, self._perp, *self._sticky, int(stuck[0]), int(stuck[1]),
            float(direction[0]), float(direction[1]), tau, stretch, rows, self._n_sub,
            self._dt_seg, x.ctypes.data, q_out.ctypes.data, dq_out.ctypes.data,
        )  # fmt: skip
        state = (float(x[0]), float(x[1]), float(x[2]), float(x[3]))
        return int(done), state, q_out[:done], dq_out[:done]


def main() -> int:
    """Build (or find) the compiled step and print which step the open-loop simulation runs;
    exit 0 either way (the Python step is a working fallback)."""
    return native_build.print_kernel_status("hil", "open-loop step", kernel_status)


if __name__ == "__main__":
    sys.exit(main())
