"""Process life of a run: exit signals, and whether the process that wrote a run still lives.

* :func:`run_command_line`: every way into a command line passes here, so each installs the
  exit signals below before its imports (the one place that does).
* :func:`install_exit_signals`: SIGTERM and SIGHUP behave like Ctrl-C (a ``KeyboardInterrupt``
  in the main thread), so every way of stopping a run goes through the same safe path: zero
  torque, drives disabled, meta.json closed. Signals that arrive while that path runs are not
  allowed to cut it short (the third one ends the process at once, for a hung clean-up). A
  signal during the command line's own import ends the process at once with one line (nothing
  runs yet); one that lands in a later import is acted on as soon as that import is done.
* :func:`process_stamp` / :func:`run_status`: a run's meta.json says ``running`` while its
  writer is at work; if the writer is killed (SIGKILL, power loss) the file keeps saying so.
  The stamp (pid, host, boot id, process start time) lets a reader tell such a run from a live
  one: :func:`run_status` reports it as ``died``.

Imports nothing of this project; both command lines (``hil``, ``virtual-robot``) use it.
"""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import sys
from collections.abc import Callable, Mapping
from types import FrameType
from typing import Any

EXIT_SIGNALS = ("SIGINT", "SIGTERM", "SIGHUP")
IMPORT_RETRY_S = 0.005  # a signal during an import is acted on once the import is done
_received: list[int] = []  # exit signals received so far (the first one is what stopped us)
_loading: list[str] = []  # the program whose command line is being imported (nothing runs yet)
_drives: list[bool] = []  # a link to drives was opened in this process (drivers.arm.Arm)


def _on_exit_signal(signum: int, frame: FrameType | None) -> None:
    _received.append(signum)
    if len(_received) == 1 and _loading:
        # The command line's own import (numpy, scipy, Pinocchio: seconds on a loaded machine)
        # has started nothing and written nothing: end now, not when the import is done.
        print(f"{_loading[0]}: {interrupt_reason()}; nothing was running yet", file=sys.stderr)
        sys.stderr.flush()
        os._exit(interrupt_exit_code())
    if len(_received) == 1:
        _interrupt_when_safe(frame)
        return
    name = signal.Signals(signum).name
    if len(_received) >= 3:  # the clean-up hangs: the user insists
        print(f"{_prog()}: {name} again; exiting without clean-up", file=sys.stderr, flush=True)
        os._exit(128 + _received[0])
    print(f"{_prog()}: {name}: already stopping (drives being disabled)", file=sys.stderr)


def _importing(frame: FrameType | None) -> bool:
    while frame is not None:
        if frame.f_code.co_filename.startswith("<frozen importlib"):
            return True
        frame = frame.f_back
    return False


def _interrupt_when_safe(frame: FrameType | None) -> None:
    """Raise KeyboardInterrupt now, unless the main thread is importing a module: an
    exception inside a C extension's import turns into a confusing ImportError (numpy's
    does), so try again every few ms (SIGALRM) until the import is done."""
    if not _importing(frame):
        raise KeyboardInterrupt
    signal.signal(signal.SIGALRM, _retry_interrupt)
    signal.setitimer(signal.ITIMER_REAL, IMPORT_RETRY_S)


def _retry_interrupt(_signum: int, frame: FrameType | None) -> None:
    _interrupt_when_safe(frame)


def _prog() -> str:
    return os.path.basename(sys.argv[0]) or "python"


def limit_blas_threads() -> None:
    """One BLAS thread for this process (and the processes it starts), called where a command
    starts, never on import.

    The matrices here are small (at most about 8000×9) and the machine may have two cores shared
    with a realtime loop: OpenBLAS worker threads spin, steal the loop's core and made an 8000×9
    least-squares solve 10× slower under load. Before numpy is loaded the environment variable
    does it (children inherit it); after, threadpoolctl limits the loaded library.
    """
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    if "numpy" in sys.modules:
        from threadpoolctl import threadpool_limits

        threadpool_limits(limits=1, user_api="blas")


# glibc's malloc gives a freed block back to the system at once only when it was mmapped, and
# raises its mmap threshold to the size of every mmapped block freed (up to 32 MB): after the
# first few, the 1–30 MB arrays of a long analysis come from the heap, whose freed middle stays
# resident. A 10-minute diagnosis at 1 kHz held 300–600 MB of freed heap that way (resident
# against live memory, tracemalloc; docs/diagnosis.md, "Memory and long recordings"). A fixed
# low threshold would return them but page-fault every large array afresh (a third more CPU
# time there); trimming the heap between an analysis's stages returns it at no such cost.


def release_freed_heap() -> bool:
    """Return the heap's freed pages to the system (glibc ``malloc_trim``): for analyses
    between stages whose arrays are freed. Changes nothing but the resident size. False where
    the C library has no ``malloc_trim`` (not glibc): nothing done."""
    import ctypes

    try:
        trim = ctypes.CDLL(None).malloc_trim  # the C library this interpreter runs on
    except (OSError, AttributeError):
        return False
    trim.argtypes, trim.restype = [ctypes.c_size_t], ctypes.c_int
    trim(0)
    return True


def install_exit_signals() -> None:
    """SIGINT, SIGTERM and SIGHUP raise KeyboardInterrupt once in the main thread."""
    for name in EXIT_SIGNALS:
        with contextlib.suppress(ValueError, OSError, AttributeError):  # not the main thread
            signal.signal(getattr(signal, name), _on_exit_signal)


def run_command_line(
    prog: str, load_main: Callable[[], Callable[[Any], int]], argv: Any = None
) -> int:
    """A command line's way in (the ``hil`` console script, ``python -m hil``, ``python -m
    hil.cli``): the exit signals first, then ``load_main()`` (the import of the command line)
    and its ``main(argv)``. An exit signal during the import ends with one line; an interrupted
    command's 130 becomes 128 + the signal's number, as a shell reports it."""
    # loading before the handlers: a signal that lands between the first handler and the
    # last (a test sent SIGINT as soon as SIGINT's was in) ends with the one line too
    _loading.append(prog)
    try:
        install_exit_signals()
        main = load_main()
        _loading.clear()
        code = main(argv)
    except KeyboardInterrupt:
        print(f"{prog}: {interrupt_reason()}; nothing was running yet", file=sys.stderr)
        return interrupt_exit_code()
    finally:
        _loading.clear()
    return interrupt_exit_code() if code == 130 else code


def exit_signal() -> int | None:
    """The first exit signal received (signal number), or None."""
    return _received[0] if _received else None


def interrupt_reason() -> str:
    """One line saying what stopped the process: Ctrl-C or the signal's name."""
    signum = exit_signal()
    if signum is None or signum == signal.SIGINT:
        return "interrupted by the user (Ctrl-C)"
    return f"stopped by {signal.Signals(signum).name}"


def note_drives_opened() -> None:
    """A link to drives is being opened in this process (every way out disables them)."""
    _drives[:] = [True]


def stopped_line() -> str:
    """What an interrupted command says: what stopped it, and that the drives are at zero
    torque and disabled where this process drove any (an offline analysis drives none)."""
    if _drives:
        return f"{interrupt_reason()}; drives at zero torque and disabled"
    return interrupt_reason()


def interrupt_exit_code() -> int:
    """128 + the signal number, as a shell reports a process a signal ended (130 for Ctrl-C)."""
    return 128 + (exit_signal() or signal.SIGINT)


# ---- who is running a run --------------------------------------------------------------
def _boot_id() -> str:
    try:
        with open("/proc/sys/kernel/random/boot_id") as f:
            return f.read().strip()
    except OSError:
        return ""


def _stat_fields(pid: int) -> list[bytes] | None:
    """/proc/PID/stat's fields from the third (state) on, or None (no such process, not
    Linux)."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            stat = f.read()
    except OSError:
        return None
    # the command name (field 2) may hold spaces and parentheses: split after its ')'
    return stat[stat.rindex(b")") + 2 :].split() if b")" in stat else None


def _start_ticks(pid: int) -> int | None:
    """Start time of process ``pid`` (clock ticks since boot, /proc/PID/stat field 22)."""
    fields = _stat_fields(pid)
    try:
        return int(fields[19]) if fields else None
    except (ValueError, IndexError):
        return None


def cpu_ticks(pid: int) -> int | None:
    """CPU time process ``pid`` has used, user + system (clock ticks, /proc/PID/stat fields 14
    and 15), or None where it cannot be read: whether a process is still working."""
    fields = _stat_fields(pid)
    try:
        return int(fields[11]) + int(fields[12]) if fields else None
    except (ValueError, IndexError):
        return None


def process_stamp() -> dict[str, Any]:
    """meta.json's ``process``: enough to tell later whether this very process still runs."""
    pid = os.getpid()
    return {
        "process": {
            "pid": pid,
            "host": socket.gethostname(),
            "boot_id": _boot_id(),
            "start_ticks": _start_ticks(pid),
        }
    }


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process: it exists
        return True
    return True


def run_status(meta: Mapping[str, Any]) -> str:
    """A run's status as a reader should report it.

    meta.json's ``status``, except that a ``running`` run whose writer can be checked (this host,
    this boot) and is gone, or is another process under a reused pid, is ``died``: it never
    finished and never will. A run from another host or boot, or without a stamp, keeps what
    the file says.
    """
    status = str(meta.get("status", "unknown"))
    stamp = meta.get("process")
    if status != "running" or not isinstance(stamp, Mapping):
        return status
    pid, host, boot = stamp.get("pid"), stamp.get("host"), stamp.get("boot_id")
    if not isinstance(pid, int) or isinstance(pid, bool) or pid <= 0:
        return status
    if host != socket.gethostname() or not boot or boot != _boot_id():
        return status  # cannot check from here
    if not _alive(pid):
        return "died"
    ticks = stamp.get("start_ticks")
    if isinstance(ticks, int) and _start_ticks(pid) not in (None, ticks):
        return "died"  # the pid belongs to another process now
    return status


STDOUT_CLOSED = (
    "standard output is closed, so the result would be lost; give it somewhere to go "
    "(> FILE, or > /dev/null to discard it)"
)


def stdout_closed() -> bool:
    """Whether this process was started with its standard output closed (``>&-``): what a
    command prints there would be lost without a word (Python's ``print`` then writes
    nowhere), so a command refuses to start (exit status 2, :data:`STDOUT_CLOSED`)."""
    if sys.stdout is None:
        return True
    try:
        fd = sys.stdout.fileno()
    except (OSError, ValueError):  # a stream in memory (a test's capture): nothing is lost
        return False
    try:
        os.fstat(fd)
    except OSError:
        return True
    return False


def reader_gone() -> int:
    """Exit status after stdout's reader closed the pipe: the shell's own for a writer that
    SIGPIPE ended (128 + 13), quietly; what is left in Python's buffer goes to /dev/null so that
    the interpreter's flush at exit raises nothing more."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())
    os.close(devnull)
    return 128 + signal.SIGPIPE
