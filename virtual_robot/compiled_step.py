"""The compiled RK4 step of the n-joint plant (issue 14's speed target): builds
``rk4_aba.cpp`` against the Pinocchio C++ library that the ``pin`` wheel installs, loads it
through ctypes, and gives :class:`CompiledArm`, which :class:`virtual_robot.urdf_plant.UrdfPlant`
calls for the RK4 substeps of a control period in one stick mode, to locate a stick, and for
the offline simulation's control periods with their stick events and breakaways.

The shared library is built once per source and toolchain, lazily on first use (or by
``make`` setup: ``python -m virtual_robot.compiled_step``), into a cache directory
(:func:`drivers.native_build.cache_dir`) under a name keyed by the hash of the source, the
compiler, its flags and the Pinocchio version (a cached library is used even when the compiler
is gone later), under a file lock so concurrent processes build it once; a compile is bounded
by :data:`BUILD_TIMEOUT_S` (all of it :func:`drivers.native_build.build_cached`). When the
compiler or the headers are missing or the build fails, the plant runs the Python step and
says so in one line (:func:`kernel_status`); a failed compile is remembered beside the library
so later runs do not retry it.

``DDBENCH_PLANT_KERNEL`` chooses: ``auto`` (default: compiled when it builds), ``python``
(always the Python step), ``compiled`` (refuse to run without it).

Imports the standard library, numpy, pinocchio (for its install prefix) and
:mod:`drivers.native_build` (the build cache it shares with the host's compiled open-loop step).
"""

from __future__ import annotations

import ctypes
import os
import shutil
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from drivers import native_build
from drivers.native_build import CACHE_ENV as CACHE_ENV  # re-exported for its callers
from drivers.native_build import (
    ERROR_CHARS,
    KernelUnavailableError,
    build_cached,
    cached_name,
)
from drivers.native_build import KernelStatus as KernelStatus  # re-exported: urdf_plant

SOURCE = Path(__file__).with_name("rk4_aba.cpp")
KERNEL_ENV = "DDBENCH_PLANT_KERNEL"
# about 50 s of CPU quiet (32 s of it the front end), longer on a loaded machine: a generous bound
BUILD_TIMEOUT_S = 600.0
# The compile flags. No -ffast-math and no FMA contraction: the kernel must round exactly as
# numpy does in urdf_plant._rk4_aba. The definitions are those of Pinocchio's exported CMake
# targets (pinocchio_headers, pinocchio_default, pinocchio_parsers), so ABA and the URDF
# parser are the library's explicit instantiations, the code pin.aba runs.
CXXFLAGS = ("-O2", "-std=c++17", "-fPIC", "-shared", "-ffp-contract=off", "-DNDEBUG")
DEFINES = (
    "PINOCCHIO_ENABLE_TEMPLATE_INSTANTIATION",
    "BOOST_MPL_LIMIT_LIST_SIZE=30",
    "BOOST_MPL_LIMIT_VECTOR_SIZE=30",
    "BOOST_MPL_CFG_NO_PREPROCESSED_HEADERS",
    "BOOST_FUSION_INVOKE_MAX_ARITY=12",
    "PINOCCHIO_WITH_URDFDOM",
    "PINOCCHIO_URDFDOM_HEADERS_MAJOR_VERSION=3",
    "PINOCCHIO_URDFDOM_HEADERS_MINOR_VERSION=0",
    "PINOCCHIO_URDFDOM_HEADERS_PATCH_VERSION=0",
)


def pinocchio_prefix() -> Path:
    """The install prefix of the pin wheel (cmeel.prefix): include/ and lib/ of its C++ side."""
    import pinocchio

    # <prefix>/lib/python3.X/site-packages/pinocchio/__init__.py
    return Path(pinocchio.__file__).resolve().parents[4]


def build_command(output: Path) -> list[str]:
    """The compiler call; KernelUnavailableError (one line) without a compiler or a header."""
    command = _compile_command(output)
    if shutil.which(command[0]) is None:
        raise KernelUnavailableError(f"no C++ compiler {command[0]!r} on PATH")
    prefix = pinocchio_prefix()
    include = prefix / "include"
    needed = {
        "Pinocchio": include / "pinocchio" / "algorithm" / "aba.hpp",
        "Eigen (cmeel-eigen)": include / "eigen3" / "Eigen" / "Core",
        "urdfdom headers (cmeel-urdfdom-headers)": (
            include / "urdfdom_headers" / "urdf_model" / "model.h"
        ),
        "libpinocchio_default": prefix / "lib" / "libpinocchio_default.so",
    }
    missing = [name for name, path in needed.items() if not path.exists()]
    if missing:
        raise KernelUnavailableError(f"missing {', '.join(missing)} under {prefix}")
    return command


def _compile_command(output: Path) -> list[str]:
    """The compiler call, whether or not the compiler and headers are there: the library's
    cache key, so a library built earlier is found after they are gone."""
    cxx = os.environ.get("CXX", "g++")
    prefix = pinocchio_prefix()
    include = prefix / "include"
    lib = prefix / "lib"
    return [
        cxx,
        *CXXFLAGS,
        *(f"-D{d}" for d in DEFINES),
        f"-I{include}",
        f"-I{include / 'eigen3'}",
        f"-I{include / 'urdfdom_headers'}",
        f"-I{include / 'urdfdom'}",
        str(SOURCE),
        "-o",
        str(output),
        f"-L{lib}",
        "-lpinocchio_default",
        "-lpinocchio_parsers",
        f"-Wl,-rpath,{lib}",
    ]


def library_path() -> Path:
    """Where the library of this source and toolchain is (or will be) cached."""
    import pinocchio

    parts = (*_compile_command(Path("OUT")), pinocchio.__version__, sys.platform)
    return cached_name(SOURCE, parts)


def build(timeout_s: float = BUILD_TIMEOUT_S) -> Path:
    """The compiled library, built if not cached; KernelUnavailableError (one line) if not."""
    what = "the compiled plant step (about a minute of CPU)"
    return build_cached(SOURCE, library_path(), build_command, timeout_s, what)


_LIBRARIES: dict[Path, ctypes.CDLL] = {}


def load() -> ctypes.CDLL:
    """The compiled library (built on first use), or KernelUnavailableError saying why not."""
    path = build()
    if path not in _LIBRARIES:
        try:
            lib = ctypes.CDLL(str(path))
        except OSError as exc:
            raise KernelUnavailableError(f"loading {path.name}: {exc}") from None
        lib.ddb_arm_new.restype = ctypes.c_void_p
        lib.ddb_arm_new.argtypes = [ctypes.c_char_p, ctypes.c_double, ctypes.c_void_p,
                                    ctypes.c_int, ctypes.c_char_p, ctypes.c_int]  # fmt: skip
        lib.ddb_arm_free.argtypes = [ctypes.c_void_p]
        lib.ddb_locked.restype = ctypes.c_void_p
        lib.ddb_locked.argtypes = [ctypes.c_void_p, ctypes.c_int, ctypes.c_void_p,
                                   ctypes.c_void_p, ctypes.c_char_p, ctypes.c_int]  # fmt: skip
        lib.ddb_locked_params.restype = ctypes.c_int
        lib.ddb_locked_params.argtypes = [ctypes.c_void_p, ctypes.c_void_p]
        lib.ddb_locate.restype = ctypes.c_int
        lib.ddb_locate.argtypes = [ctypes.c_void_p] * 9 + [ctypes.c_double] + [
            ctypes.c_void_p] * 4 + [ctypes.c_int]  # fmt: skip
        lib.ddb_step.restype = ctypes.c_int
        lib.ddb_step.argtypes = [ctypes.c_void_p] * 6 + [ctypes.c_double] + [
            ctypes.c_void_p] * 4 + [ctypes.c_int]  # fmt: skip
        lib.ddb_accelerations.restype = ctypes.c_int
        lib.ddb_accelerations.argtypes = [ctypes.c_void_p] * 8 + [ctypes.c_int]
        lib.ddb_advance.restype = ctypes.c_int
        lib.ddb_advance.argtypes = [ctypes.c_void_p] * 10 + [ctypes.c_double] * 2 + [
            ctypes.c_void_p] * 4 + [ctypes.c_int]  # fmt: skip
        lib.ddb_arm_friction.restype = ctypes.c_int
        lib.ddb_arm_friction.argtypes = [ctypes.c_void_p] * 7 + [ctypes.c_int]
        lib.ddb_run_periods.restype = ctypes.c_int
        lib.ddb_run_periods.argtypes = [ctypes.c_void_p] * 9 + [ctypes.c_int] * 2 + [
            ctypes.c_double] * 2 + [ctypes.c_void_p] * 6 + [ctypes.c_int]  # fmt: skip
        _LIBRARIES[path] = lib
    return _LIBRARIES[path]


def kernel_status() -> KernelStatus:
    """Which step an n-joint plant made now would run, and why not compiled (one line)."""
    return native_build.kernel_status(KERNEL_ENV, load, library_path, "compiled plant step")


# ddb_advance's outcomes, and ddb_run_periods' after a period out of bounds
REACHED, CROSSED, BREAKS, OUT_OF_BOUNDS = 0, 1, 2, 3
_ROWS = ("q", "v", "c", "b", "watch", "q_cross", "v_cross", "command", "upper", "lower", "a",
         "booked", "max_speed", "q_limit", "direction", "crossed", "v_end", "stuck",
         "slip")  # fmt: skip


class CompiledArm:
    """One arm's model in the compiled kernel (built from the same URDF, gravity and armature
    as the plant's Pinocchio model), its locked-joint models, and the preallocated buffers a
    call passes by address."""

    def __init__(self, urdf: str, gravity_m_s2: float, armature: Sequence[float]) -> None:
        self._lib = load()
        self.n = n = len(armature)
        self._armature = np.ascontiguousarray(armature, dtype=float)
        self._error = ctypes.create_string_buffer(ERROR_CHARS)
        handle = self._lib.ddb_arm_new(
            urdf.encode(), gravity_m_s2, self._armature.ctypes.data, n, self._error, ERROR_CHARS
        )
        if not handle:
            raise KernelUnavailableError(f"{urdf}: {self._message()}")
        self._handle = handle
        # the n-vectors of a call (_ROWS), rows of one buffer; then the scalars [t,
        # dissipated, steps, dt of the crossing step, its viscous work]
        self._rows = np.zeros((len(_ROWS), n))
        self._scalars = np.zeros(9)  # also ddb_step's work in [4]; ddb_run_periods' [5]..[8]
        self._buf = dict(zip(_ROWS, self._rows, strict=True))
        addr, stride = self._rows.ctypes.data, self._rows.strides[0]
        self._addr = {name: addr + i * stride for i, name in enumerate(_ROWS)}
        self._scalars_addr = self._scalars.ctypes.data
        # the arrays last copied into the "b" and "watch" rows (the callers' arrays are never
        # changed in place, so the same object holds the same values)
        self._b_loaded: np.ndarray | None = None
        self._watch_loaded: np.ndarray | None = None

    def _message(self) -> str:
        return self._error.value.decode(errors="replace")

    def _crossing(self) -> tuple[float, tuple[np.ndarray, np.ndarray, float]]:
        """What the kernel left after a CROSSED substep: (dt, (q, q̇, its viscous work))."""
        s, buf = self._scalars, self._buf
        return float(s[3]), (buf["q_cross"].copy(), buf["v_cross"].copy(), float(s[4]))

    def __del__(self) -> None:
        handle = getattr(self, "_handle", None)
        if handle:
            self._lib.ddb_arm_free(handle)  # with its locked arms
            self._handle = None

    def locked(self, stuck: np.ndarray, q: np.ndarray) -> int:
        """The kernel's arm with the joints ``stuck`` (indices) locked at ``q`` (Pinocchio's
        reduced model, as UrdfPlant._locked_arm): one per stuck set, built the first time that
        set sticks and refreshed in place for other positions (rk4_aba.cpp, ddb_locked: only
        the placements and inertias q_S enters, by buildReducedModel's own expressions). The
        handle is valid until the same set is locked at other positions (the plant asks once
        per stick mode)."""
        idx = np.ascontiguousarray(stuck, dtype=np.intc)
        q_ref = np.ascontiguousarray(q, dtype=float)
        handle = self._lib.ddb_locked(
            self._handle, idx.size, idx.ctypes.data, q_ref.ctypes.data, self._error, ERROR_CHARS
        )
        if not handle:
            raise RuntimeError(f"compiled plant step: {self._message()}")
        return handle

    def locked_params(self, locked: int) -> np.ndarray:
        """The locked arm's joint placements and inertias, one row of 22 per sliding joint
        (rotation row major, translation, mass, lever, inertia xx, xy, yy, xz, yz, zz): what
        the tests compare with Pinocchio's buildReducedModel."""
        out = np.zeros((self.n, 22))
        rows = self._lib.ddb_locked_params(locked, out.ctypes.data)
        return out[:rows]

    def _load(self, q: np.ndarray, v: np.ndarray, c: np.ndarray, b: np.ndarray | None) -> int:
        buf = self._buf
        buf["q"][:] = q
        buf["v"][:] = v
        buf["c"][:] = c
        if b is None:
            return 0  # NULL: no viscous friction
        if b is not self._b_loaded:  # the plant's b: loaded once (it never changes in place)
            buf["b"][:] = b
            self._b_loaded = b
        return self._addr["b"]

    def step(
        self,
        locked: int | None,
        q: np.ndarray,
        v: np.ndarray,
        tau_minus_level: np.ndarray,
        b: np.ndarray | None,
        dt: float,
    ) -> tuple[np.ndarray, np.ndarray, float]:
        """One RK4 step of dt of the mode (UrdfPlant._rk4_mode): every joint sliding (locked
        None) or the arm ``locked`` (:meth:`locked`). Returns (q, q̇, ∫bᵀq̇² dt)."""
        a, buf = self._addr, self._buf
        b_addr = self._load(q, v, tau_minus_level, b)
        s4 = self._scalars_addr + 4 * self._scalars.itemsize
        if self._lib.ddb_step(
            self._handle, locked, a["q"], a["v"], a["c"], b_addr or None, dt, a["q_cross"],
            a["v_cross"], s4, self._error, ERROR_CHARS,
        ):  # fmt: skip
            raise RuntimeError(f"compiled plant step: {self._message()}")
        return buf["q_cross"].copy(), buf["v_cross"].copy(), float(self._scalars[4])

    def locate(
        self,
        locked: int | None,
        q: np.ndarray,
        v: np.ndarray,
        tau_minus_level: np.ndarray,
        b: np.ndarray | None,
        direction: np.ndarray,
        crossed: np.ndarray,
        v_end: np.ndarray,
        dt: float,
    ) -> tuple[float, int, tuple[np.ndarray, np.ndarray, float]]:
        """virtual_robot.stick_slip.locate_stick in the kernel (ddb_locate: scipy's Brent's
        method on the mode's RK4 flow map, the same iterates): the first of the ``crossed``
        joints whose velocity times ``direction`` reaches zero within [0, dt] from (q, q̇),
        ``v_end`` the flow's q̇ at dt. Returns (s, joint, (q, q̇, ∫bᵀq̇² dt) at s)."""
        a, buf = self._addr, self._buf
        b_addr = self._load(q, v, tau_minus_level, b)
        buf["direction"][:] = direction
        buf["crossed"][:] = crossed
        buf["v_end"][:] = v_end
        status = self._lib.ddb_locate(
            self._handle, locked, a["q"], a["v"], a["c"], b_addr or None, a["direction"],
            a["crossed"], a["v_end"], dt, self._scalars_addr, a["q_cross"], a["v_cross"],
            self._error, ERROR_CHARS,
        )  # fmt: skip
        if status == -2:  # where scipy's brentq raises
            raise ValueError(f"locating a stick: {self._message()}")
        if status:
            raise RuntimeError(f"compiled plant step: {self._message()}")
        s = self._scalars
        return float(s[0]), int(s[1]), (buf["q_cross"].copy(), buf["v_cross"].copy(), float(s[2]))

    def accelerations(
        self,
        locked: int | None,
        q: np.ndarray,
        v: np.ndarray,
        tau_minus_level: np.ndarray,
        b: np.ndarray | None,
    ) -> np.ndarray:
        """q̈ of the mode at (q, q̇) (UrdfPlant._accelerations)."""
        a = self._addr
        b_addr = self._load(q, v, tau_minus_level, b)
        if self._lib.ddb_accelerations(
            self._handle, locked, a["q"], a["v"], a["c"], b_addr or None, a["a"], self._error,
            ERROR_CHARS,
        ):  # fmt: skip
            raise RuntimeError(f"compiled plant step: {self._message()}")
        return self._buf["a"].copy()

    def advance(
        self,
        q: np.ndarray,
        v: np.ndarray,
        tau_minus_level: np.ndarray,
        b: np.ndarray | None,
        watch: np.ndarray,
        t: float,
        t_end: float,
        max_step_s: float,
        dissipated: float,
        stuck: tuple[int, np.ndarray, tuple[np.ndarray, np.ndarray]] | None = None,
    ) -> tuple[np.ndarray, np.ndarray, float, float, int, int, tuple | None]:
        """RK4 substeps of min(max_step_s, t_end − t) from (q, q̇) at t in one stick mode, as
        UrdfPlant.advance_to takes them: every joint sliding under the held τ − level (viscous
        b, or None), or with ``stuck`` = (handle from :meth:`locked`, the command τ, the stuck
        joints' bands (upper, lower)), Karnopp's test before each substep. Until t_end, the
        first substep where a watched velocity changes sign, or the first where a stuck joint
        breaks away. Returns (q, q̇, t, dissipated, accepted steps, outcome, crossing): outcome
        REACHED, CROSSED or BREAKS (before that substep); crossing, when CROSSED, is (dt, (q,
        q̇, ∫bᵀq̇² dt)) of the substep for the plant to locate the stick in."""
        buf, a = self._buf, self._addr
        b_addr = self._load(q, v, tau_minus_level, b)
        if watch is not self._watch_loaded:  # the plant's, new at each stick mode
            buf["watch"][:] = watch
            self._watch_loaded = watch
        locked = None
        if stuck is not None:
            locked, command, (upper, lower) = stuck
            buf["command"][:] = command
            buf["upper"][: upper.size] = upper
            buf["lower"][: lower.size] = lower
        s = self._scalars
        s[0], s[1], s[2] = t, dissipated, 0.0
        outcome = self._lib.ddb_advance(
            self._handle, locked, a["q"], a["v"], a["c"], b_addr or None, a["watch"],
            a["command"], a["upper"], a["lower"], t_end, max_step_s, self._scalars_addr,
            a["q_cross"], a["v_cross"], self._error, ERROR_CHARS,
        )  # fmt: skip
        if outcome < 0:
            raise RuntimeError(f"compiled plant step: {self._message()}")
        crossing = self._crossing() if outcome == CROSSED else None
        return (
            buf["q"].copy(), buf["v"].copy(), float(s[0]), float(s[1]), int(s[2]), outcome,
            crossing,
        )  # fmt: skip

    def set_friction(
        self,
        sticky: np.ndarray,
        coulomb: tuple[np.ndarray, np.ndarray],
        band: tuple[np.ndarray, np.ndarray],
    ) -> None:
        """The plant's friction per joint for :meth:`run_periods`: which joints can stick,
        their Coulomb levels and static bands (positive, negative direction)."""
        arrays = [np.ascontiguousarray(a, dtype=float) for a in (sticky, *coulomb, *band)]
        if self._lib.ddb_arm_friction(
            self._handle, *(a.ctypes.data for a in arrays), self._error, ERROR_CHARS
        ):
            raise RuntimeError(f"compiled plant step: {self._message()}")

    def run_periods(
        self,
        q: np.ndarray,
        v: np.ndarray,
        b: np.ndarray | None,
        stuck: np.ndarray,
        slip_dir: np.ndarray,
        command: np.ndarray,
        booked: np.ndarray,
        torques: np.ndarray,
        n0: int,
        period_s: float,
        max_step_s: float,
        bounds: tuple[np.ndarray, np.ndarray],
        totals: tuple[float, float, float],
        q_out: np.ndarray,
        v_out: np.ndarray,
    ) -> tuple[bool, int, tuple[np.ndarray, ...], tuple[float, float, float, int, int, int]]:
        """The control periods of ``torques`` (rows, C-contiguous) one after another from (q,
        q̇) in the stick mode (``stuck``, ``slip_dir``) at t, period j ending at (n0 + j) ·
        period_s, each as UrdfPlant.command then advance_to take it, stick events and
        breakaways included (ddb_run_periods, after :meth:`set_friction`); the work since
        the last booking (from ``booked`` under ``command``) booked at each start; each
        period's end state into the rows of q_out, v_out. Until the periods end or one ends
        outside ``bounds`` (max |q̇|, max |q| per joint). ``totals``: (t, dissipated, work).
        Returns (whether every period ended inside the bounds; the period index where it
        stopped; (q, q̇, stuck, slip direction, the q of the last booking); (t, dissipated,
        work, accepted steps, stick events, mode changes))."""
        buf, a = self._buf, self._addr
        b_addr = self._load(q, v, command, b)  # (c is set per period by the kernel)
        buf["stuck"][:] = stuck
        buf["slip"][:] = slip_dir
        buf["command"][:] = command
        buf["booked"][:] = booked
        buf["max_speed"][:], buf["q_limit"][:] = bounds
        s = self._scalars
        s[0], s[1], s[2], s[5] = totals[0], totals[1], 0.0, totals[2]
        outcome = self._lib.ddb_run_periods(
            self._handle, a["q"], a["v"], b_addr or None, a["stuck"], a["slip"], a["command"],
            torques.ctypes.data, a["booked"], torques.shape[0], n0, period_s, max_step_s,
            a["max_speed"], a["q_limit"], self._scalars_addr, q_out.ctypes.data,
            v_out.ctypes.data, self._error, ERROR_CHARS,
        )  # fmt: skip
        if outcome < 0:
            raise RuntimeError(f"compiled plant step: {self._message()}")
        state = tuple(buf[k].copy() for k in ("q", "v", "stuck", "slip", "booked"))
        counts = (float(s[0]), float(s[1]), float(s[5]), int(s[2]), int(s[7]), int(s[8]))
        return outcome == REACHED, int(s[6]), state, counts


def main() -> int:
    """Build (or find) the compiled step and print one line saying which step the plant runs;
    exit 0 either way (the Python step is a working fallback)."""
    return native_build.print_kernel_status("virtual-robot", "plant step", kernel_status)


if __name__ == "__main__":
    sys.exit(main())
