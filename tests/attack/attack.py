"""The issue-31 attack battery: hostile files, options, profiles, signals at random moments, hub
junk and floods, concurrent runs and attaches, each against the command line as a user runs it.

Per attempt it reports the exit code, a traceback (yes/no), the error in one line (yes/no), the
run kept (its meta.json readable and not left ``running`` by a process that ended), strict JSON
(``--json`` output parsed refusing NaN/Infinity) and, for the served robot, its state after (a
later ``hil run --attach`` succeeds, with ``--clear-faults`` if need be). It exits 1 on any
traceback, lost run, invalid JSON or robot a ``--clear-faults`` rerun cannot recover.

    python tests/attack/attack.py [--quick] [--seed N] [--json]

Loopback only; every loop is bounded in count and time; every process it starts is in its own
session and killed (by its process group id) at the end of its attempt.
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import random
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections import Counter
from collections.abc import Callable, Iterator
from contextlib import contextmanager, suppress
from dataclasses import asdict, dataclass, field
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests/: cli_run
from cli_run import ROOT, wait_rows

from drivers.process import run_status

HIL = [sys.executable, "-m", "hil.entry"]
ROBOT = [sys.executable, "-m", "virtual_robot.entry"]  # as the console script
TIMEOUT_S = 120.0  # any one command; past it the attempt is a hang (reported, killed)


@dataclass
class Attempt:
    category: str
    name: str
    code: int | None = None
    traceback: bool = False
    one_line: bool = True
    data_kept: bool | None = None  # None: no run directory to check
    json_ok: bool | None = None  # None: --json not asked or nothing printed
    robot_ok: bool | None = None  # None: no served robot involved
    note: str = ""
    failures: list[str] = field(default_factory=list)

    def failed(self) -> bool:
        return bool(self.failures)


def _reject_constant(name: str) -> None:
    raise ValueError(f"not strict JSON: {name}")


def strict_loads(text: str) -> object:
    return json.loads(text, parse_constant=_reject_constant)


# ---- processes ------------------------------------------------------------------------------

_LIVE: list[subprocess.Popen] = []


def spawn(argv: list[str], cwd: Path, **kw) -> subprocess.Popen:
    """``argv`` in its own session (so its robot can be reaped by group id), output captured."""
    proc = subprocess.Popen(
        argv,
        cwd=cwd,
        stdout=kw.pop("stdout", subprocess.PIPE),
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        **kw,
    )
    _LIVE.append(proc)
    return proc


def reap(proc: subprocess.Popen) -> None:
    """Kill what is left of ``proc``'s process group (its robot, say) and wait for it."""
    with suppress(ProcessLookupError, PermissionError):
        os.killpg(proc.pid, signal.SIGKILL)
    with suppress(subprocess.TimeoutExpired):
        proc.wait(timeout=10)
    if proc in _LIVE:
        _LIVE.remove(proc)


def finish(
    proc: subprocess.Popen, timeout: float = TIMEOUT_S, *, keep_group: bool = False
) -> tuple[int | None, str, str]:
    """Wait for ``proc``; (exit code or None for a hang, stdout, stderr). Its group is reaped
    unless ``keep_group`` (the caller checks what it left, then reaps it)."""
    try:
        out, err = proc.communicate(timeout=timeout)
        code: int | None = proc.returncode
    except subprocess.TimeoutExpired:
        reap(proc)
        out, err = proc.communicate()
        code = None
    if not keep_group:
        reap(proc)
    return code, out or "", err or ""


# ---- judging an attempt ---------------------------------------------------------------------


def judge(
    a: Attempt,
    code: int | None,
    out: str,
    err: str,
    *,
    run_dir: Path | None = None,
    want_json: bool = False,
    ok_codes: tuple[int, ...] = (0, 2),
) -> Attempt:
    a.code = code
    a.traceback = "Traceback (most recent call last)" in err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    # the error line of a refusal or a signal is the last; progress lines come before it
    errors = [ln for ln in lines if "error" in ln.lower()]
    a.one_line = code == 0 or len(errors) <= 1
    if not a.one_line:
        a.note = " / ".join(errors)[:300]
    if code is None:
        a.failures.append("hang (killed after the timeout)")
    elif code not in ok_codes:
        a.failures.append(f"exit {code} not in {ok_codes}")
    if a.traceback:
        a.failures.append("traceback")
    if code not in (None, 0) and not lines and code != -signal.SIGKILL:
        a.failures.append("failed without a word")
    if want_json and (code == 0 or out.strip()):
        try:
            strict_loads(out)
            a.json_ok = True
        except ValueError as exc:
            a.json_ok = False
            a.failures.append(f"invalid JSON: {exc}"[:120])
    if run_dir is not None:
        # SIGKILL cannot be caught: a launch it cuts short may leave its robot's log (no run
        # was recorded, nothing is lost; reported in the note)
        check_run_dir(a, run_dir, refused=code not in (0, 1, -signal.SIGKILL))
        if code == -signal.SIGKILL and run_dir.is_dir() and not any(run_dir.rglob("meta.json")):
            left = sorted(str(p.relative_to(run_dir)) for p in run_dir.rglob("*") if p.is_file())
            if left:
                a.note = f"no run began; left {left[:3]}"
    if not a.note and lines:
        a.note = lines[-1][:110]
    return a


def check_run_dir(a: Attempt, run_dir: Path, *, refused: bool = True) -> None:
    """The run kept: every meta.json under ``run_dir`` (its own, and those of the runs a command
    makes on its way, as `hil identify`'s ``fit/``) parses and is not ``running`` (unless its
    writer was SIGKILLed: then the reader must see ``died``). No meta.json and a refusal
    (``refused``): nothing left behind to refuse the rerun."""
    metas = (
        [run_dir / "meta.json", *sorted(run_dir.glob("*/meta.json"))] if run_dir.is_dir() else []
    )
    metas = [m for m in metas if m.exists()]
    if not metas:
        leftovers = sorted(p.name for p in run_dir.iterdir()) if run_dir.is_dir() else []
        bare = [p for p in leftovers if not (run_dir / p).is_dir() or any((run_dir / p).iterdir())]
        a.data_kept = not bare or not refused
        if bare and refused:
            a.failures.append(f"no meta.json but left {bare[:4]}")
        return
    a.data_kept = True
    for meta_path in metas:
        try:
            meta = strict_loads(meta_path.read_text())
        except (ValueError, OSError) as exc:
            a.data_kept = False
            a.failures.append(f"{meta_path.name} unreadable: {exc}"[:120])
            continue
        status = run_status(meta) if isinstance(meta, dict) else "?"
        if status in ("running", "?"):
            a.data_kept = False
            a.failures.append(
                f"run {meta_path.parent.name} left {status!r} after its process ended"
            )
        csv = meta_path.parent / "signals.csv"
        rows = meta.get("rows") if isinstance(meta, dict) else None
        if status == "complete" and isinstance(rows, int) and csv.is_file():
            with csv.open("rb") as f:
                lines = sum(1 for _ in f) - 1
            if lines != rows:  # two writers, or a torn file
                a.data_kept = False
                a.failures.append(f"meta.json says {rows} rows, signals.csv has {lines}")


def merge(a: Attempt, subs: list[Attempt]) -> None:
    """``a``: the attempt of several processes at once (``subs``), its worst of each."""
    a.failures += [f for sub in subs for f in sub.failures]
    a.traceback = any(sub.traceback for sub in subs)
    a.one_line = all(sub.one_line for sub in subs)
    for name in ("json_ok", "data_kept"):
        seen = [getattr(sub, name) for sub in subs if getattr(sub, name) is not None]
        setattr(a, name, all(seen) if seen else None)
    codes = [sub.code for sub in subs if sub.code is not None]
    a.code = max(codes) if codes else None
    a.note = " | ".join(sub.note for sub in subs if not sub.one_line)


# ---- 1. malformed files ---------------------------------------------------------------------


def _good_rows(work: Path) -> str:
    """signals.csv of a 1.5 s `virtual-robot simulate`: a recording identify can fit."""
    code, _, err = finish(spawn([*ROBOT, "simulate", "--duration", "1.5", "--no-plot",
                                 "--out", str(work / "base")], work))  # fmt: skip
    if code != 0:
        raise SystemExit(f"attack: the base recording failed: {err.strip()[-300:]}")
    return (work / "base" / "signals.csv").read_text()


def malformed_files(rng: random.Random, good: str) -> dict[str, bytes]:
    lines = good.splitlines()
    return {
        "bom": ("\ufeff" + good).encode(),
        "nul-bytes": good.encode().replace(b"\n", b"\x00\n", 40),
        "no-final-newline": good.rstrip("\n").encode(),
        "huge-field": (
            lines[0] + "\n" + "1" * 5_000_000 + ",0,0,0,0\n" + good[len(lines[0]) :]
        ).encode(),
        "1e300": good.replace(lines[100], _with(lines[100], "1e300")).encode(),
        "nan": good.replace(lines[100], _with(lines[100], "nan")).encode(),
        "inf": good.replace(lines[100], _with(lines[100], "-inf")).encode(),
        "swapped-columns": (_swap(lines[0]) + "\n" + "\n".join(lines[1:]) + "\n").encode(),
        "pure-noise": bytes(rng.getrandbits(8) for _ in range(200_000)),
        "empty": b"",
        "header-only": (lines[0] + "\n").encode(),
    }


def _with(line: str, value: str) -> str:
    cells = line.split(",")
    return ",".join([cells[0], value, *cells[2:]])


def _swap(header: str) -> str:
    cells = header.split(",")
    return ",".join([cells[1], cells[0], *cells[2:]])


def attack_files(work: Path, rng: random.Random, quick: bool) -> Iterator[Attempt]:
    commands = ["identify"] if quick else ["identify", "diagnose"]
    for kind, data in malformed_files(rng, _good_rows(work)).items():
        path = work / f"{kind}.csv"
        path.write_bytes(data)
        for command in commands:
            out = work / f"files-{command}-{kind}"
            if command == "identify":
                argv = [*HIL, "identify", "--from", str(path), "--no-plot"]
            else:
                argv = [*HIL, "diagnose", str(path), "--no-plots"]
            code, so, se = finish(spawn([*argv, "--json", "--out", str(out)], work))
            a = Attempt("files", f"{command} {kind}")
            yield judge(a, code, so, se, run_dir=out, want_json=True, ok_codes=(0, 1, 2))


# ---- 2. options and profiles ----------------------------------------------------------------


def _cicese_with(work: Path, name: str, old: str, new: str) -> Path:
    text = (ROOT / "profiles" / "robots" / "cicese.toml").read_text()
    assert old in text, old
    d = work / name
    d.mkdir(exist_ok=True)
    (d / "cicese.urdf").write_text((ROOT / "profiles" / "robots" / "cicese.urdf").read_text())
    path = d / "robot.toml"
    path.write_text(text.replace(old, new))
    return path


def attack_options(work: Path, rng: random.Random, quick: bool) -> Iterator[Attempt]:
    cog = "[cogging]\nperiods_per_rev = [120, 96]\nphase_rad = [0.0, 0.0]\n"
    nan_fx = work / "fx-nan.toml"
    nan_fx.write_text(f'name = "x"\n{cog}amplitude_Nm = [nan, 0.1]\n')
    big_fx = work / "fx-big.toml"
    big_fx.write_text(f'name = "x"\n{cog}amplitude_Nm = [1e300, 0.1]\n')
    drive = work / "drive.toml"
    drive.write_text(
        (ROOT / "profiles" / "drives" / "dm1015b.toml")
        .read_text()
        .replace("watchdog_s = 0.5", "watchdog_s = 1e9")
    )
    wd_robot = _cicese_with(work, "wd", '"dm1015b"]', f'"{drive}"]')
    big_robot = _cicese_with(work, "big", "com_m = 0.091", "com_m = 1e300")
    run = ["run", "--bench", "virtual-slcan", "--duration", "0.3", "--no-plot"]
    cases: list[tuple[str, list[str]]] = [
        ("unknown --effects", [*HIL, *run, "--effects", "no-such-effect"]),
        ("NaN in effects file", [*HIL, *run, "--effects", str(nan_fx)]),
        ("cogging 1e300", [*HIL, *run, "--effects", str(big_fx)]),
        ("absurd watchdog", [*HIL, *run, "--robot", str(wd_robot)]),
        ("com_m 1e300 run", [*HIL, *run, "--robot", str(big_robot)]),
        (
            "com_m 1e300 simulate",
            [*ROBOT, "simulate", "--robot", str(big_robot), "--duration", "0.2"],
        ),
        ("--duration nan", [*HIL, "run", "--bench", "virtual-inprocess", "--duration", "nan"]),
        ("--duration -1", [*HIL, "run", "--bench", "virtual-inprocess", "--duration", "-1"]),
        ("--duration 1e300", [*HIL, "run", "--bench", "virtual-inprocess", "--duration", "1e300"]),
        ("--attach foo", [*HIL, *run[:3], "--attach", "foo"]),
        (
            "--attach port 99999",
            [*HIL, "run", "--bench", "virtual-socketcand", "--attach", "127.0.0.1:99999"],
        ),
        ("unknown --bench", [*HIL, "run", "--bench", "no-such-bench", "--duration", "0.2"]),
    ]
    if quick:
        cases = cases[:4] + cases[5:7]
    for i, (name, argv) in enumerate(cases):
        out = work / f"opt-{i}"
        code, so, se = finish(spawn([*argv, "--out", str(out)], work))
        a = judge(Attempt("options", name), code, so, se, run_dir=out, ok_codes=(2,))
        yield a


# ---- 3. signals at random moments -----------------------------------------------------------


def attack_signals(work: Path, rng: random.Random, quick: bool, base: Path) -> Iterator[Attempt]:
    commands = {
        "hil run": [
            *HIL,
            "run",
            "--bench",
            "virtual-slcan",
            "--mode",
            "realtime",
            "--duration",
            "30",
            "--no-plot",
        ],
        "hil identify": [
            *HIL,
            "identify",
            "--bench",
            "virtual-slcan",
            "--mode",
            "realtime",
            "--duration",
            "30",
            "--no-plot",
        ],
        "simulate": [*ROBOT, "simulate", "--duration", "3000", "--no-plot"],
        "serve": [*ROBOT, "serve", "--bench", "virtual-socketcand"],
    }
    sigs = [signal.SIGINT, signal.SIGTERM, signal.SIGHUP, signal.SIGKILL]
    pairs = [(c, s) for c in commands for s in sigs]
    if quick:
        pairs = rng.sample(pairs, 5)
    for n, (cmd, sig) in enumerate(pairs):
        out = work / f"sig-{n}"
        argv = list(commands[cmd]) + ([] if cmd == "serve" else ["--out", str(out)])
        delay = rng.uniform(0.1, 4.0)
        proc = spawn(argv, work)
        time.sleep(delay)
        robots = _robot_pids(out)
        with suppress(ProcessLookupError):
            proc.send_signal(sig)
        code, so, se = finish(proc, timeout=60, keep_group=True)
        expected = (0, -9) if sig == signal.SIGKILL else (0, 128 + sig)
        a = judge(
            Attempt("signals", f"{cmd} {sig.name} at {delay:.1f}s"),
            code, so, se, run_dir=None if cmd == "serve" else out, ok_codes=expected,
        )  # fmt: skip
        # the robot a killed host leaves behind must notice and exit by itself
        t_end = time.monotonic() + 5
        while robots and time.monotonic() < t_end:
            robots = [p for p in robots if _pid_alive(p)]
            time.sleep(0.1)
        if robots:
            a.failures.append(f"robot pid {robots} outlived its host by 5 s")
            for p in robots:
                with suppress(ProcessLookupError):
                    os.kill(p, signal.SIGKILL)
        reap(proc)
        yield a


def _robot_pids(out: Path) -> list[int]:
    with suppress(OSError, ValueError):
        meta = json.loads((out / "meta.json").read_text())
        pid = (meta.get("channel") or {}).get("pid")
        if isinstance(pid, int):
            return [pid]
    return []


def _pid_alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(") ", 1)[1][0] != "Z"
    except (OSError, IndexError):
        return False


# ---- 4. the served robot: hub junk, floods, half-open clients, concurrent attaches ----------


@contextmanager
def served(work: Path) -> Iterator[tuple[subprocess.Popen, int]]:
    proc = spawn([*ROBOT, "serve", "--bench", "virtual-socketcand"], work)
    try:
        assert proc.stdout is not None
        port = json.loads(proc.stdout.readline())["port"]
        yield proc, port
    finally:
        reap(proc)


def attach_argv(out: Path, port: int, *extra: str, duration: str = "0.5") -> list[str]:
    return [*HIL, "run", "--bench", "virtual-socketcand", "--attach", f"127.0.0.1:{port}",
            "--duration", duration, "--no-plot", "--json", "--out", str(out), *extra]  # fmt: skip


def robot_state(a: Attempt, work: Path, port: int, tag: str) -> None:
    """A later attach succeeds, or one with --clear-faults does; else the robot is lost."""
    for extra in ((), ("--clear-faults",)):
        out = work / f"after-{tag}-{len(extra)}"
        code, _, se = finish(spawn(attach_argv(out, port, *extra), work))
        if code == 0:
            a.robot_ok = True
            if extra:
                a.note = (a.note + " | recovered with --clear-faults")[:140]
            return
        if "Traceback" in se:
            a.failures.append("traceback in the attach after")
    a.robot_ok = False
    a.failures.append(f"robot left unusable: {se.strip().splitlines()[-1:]}")


def _connect(port: int) -> socket.socket:
    s = socket.create_connection(("127.0.0.1", port), timeout=2)
    s.settimeout(2)
    return s


def _raw(port: int) -> socket.socket:
    s = _connect(port)
    s.recv(64)  # < hi >
    s.sendall(b"< open can0 >")
    s.recv(64)
    s.sendall(b"< rawmode >")
    s.recv(64)
    return s


def hub_attacks(port: int, rng: random.Random, quick: bool) -> list[tuple[str, Callable[[], None]]]:
    def junk() -> None:
        with _connect(port) as s:
            s.sendall(bytes(rng.getrandbits(8) for _ in range(64_000)))

    def non_ascii() -> None:
        with _raw(port) as s:
            s.sendall("< send 601 8 ä ö ü 0 0 0 0 0 >".encode() * 500 + b"< < < >>>" * 500)

    def flood() -> None:
        with _raw(port) as s:
            el = b"< send 7ff 8 de ad be ef 00 11 22 33 >"
            end = time.monotonic() + 2.0
            while time.monotonic() < end:
                s.sendall(el * 200)

    def many_clients() -> None:
        socks = []
        try:
            for _ in range(80):  # past the 64-client limit
                with suppress(OSError):
                    socks.append(_connect(port))
            time.sleep(0.5)
        finally:
            for s in socks:
                s.close()

    def half_open() -> None:
        socks = [_raw(port) for _ in range(8)]  # in raw mode, never read, never close cleanly
        for s in socks:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        time.sleep(1.5)
        for s in socks:  # a reset, not a FIN: as a peer that vanished
            s.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, b"\x01\x00\x00\x00\x00\x00\x00\x00")
            s.close()

    def huge_element() -> None:
        with _raw(port) as s:
            s.sendall(b"< send 080 " + b"0" * 1_000_000)

    cases = [("junk bytes", junk), ("non-ASCII elements", non_ascii), ("flood 2 s", flood),
             ("80 clients", many_clients), ("half-open clients", half_open),
             ("1 MB element", huge_element)]  # fmt: skip
    return cases[:3] if quick else cases


def attack_hub(work: Path, rng: random.Random, quick: bool) -> Iterator[Attempt]:
    with served(work) as (robot, port):
        for name, attack in hub_attacks(port, rng, quick):
            a = Attempt("hub", name)
            try:
                attack()
            except OSError as exc:
                a.note = f"client side: {exc}"[:100]
            if robot.poll() is not None:
                a.failures.append(f"served robot exited {robot.returncode}")
                yield a
                return
            robot_state(a, work, port, f"hub-{name}")
            a.code = 0
            yield a
        # a raw client sends SYNCs while a host runs: the drives fault, a rerun clears them
        a = Attempt("hub", "second SYNC producer during a run")
        host = spawn(attach_argv(work / "hub-sync", port, duration="5"), work)
        with suppress(AssertionError):  # its SYNCs on the bus (rows recorded), or it ended
            wait_rows(work / "hub-sync", 50, host, timeout=60)
        with suppress(OSError), _raw(port) as s:
            for _ in range(50):
                s.sendall(b"< send 080 0 >")
                time.sleep(0.01)
        code, so, se = finish(host)
        judge(a, code, so, se, run_dir=work / "hub-sync", ok_codes=(0, 1, 3), want_json=True)
        robot_state(a, work, port, "hub-sync")
        yield a
        # concurrent attaches
        for k in range(1 if quick else 3):
            a = Attempt("attach", f"3 attaches at once #{k}")
            outs = [work / f"att-{k}-{i}" for i in range(3)]
            procs = [spawn(attach_argv(o, port, duration="1"), work) for o in outs]
            results = [finish(p) for p in procs]
            codes = [r[0] for r in results]
            subs = [
                judge(Attempt("attach", ""), *r, run_dir=o, ok_codes=(0, 1, 3), want_json=True)
                for r, o in zip(results, outs, strict=True)
            ]
            merge(a, subs)
            overlap = _overlapping([o for o, r in zip(outs, results, strict=True) if r[0] == 0])
            if overlap:
                a.failures.append(
                    f"two hosts drove the robot at once and both completed: {overlap}"
                )
            a.note = f"exits {codes} {a.note}".rstrip()
            robot_state(a, work, port, f"att-{k}")
            yield a


def _overlapping(outs: list[Path]) -> str:
    """Of the runs that completed, two whose SYNC phases overlap (as 'A & B'), or ''. A run's
    SYNC phase is taken as the ``duration_s`` before its ``finished_unix`` (``started_unix`` is
    when its recording was opened, before the attach's listen and SDO set-up)."""
    spans = []
    for out in outs:
        with suppress(OSError, ValueError, KeyError, TypeError):
            meta = json.loads((out / "meta.json").read_text())
            end = float(meta["finished_unix"])
            spans.append((end - float(meta["duration_s"]), end, out.name))
    spans.sort()
    for (_, end, name), (start, _, other) in itertools.pairwise(spans):
        if start < end:
            return f"{name} & {other} ({end - start:.2f} s)"
    return ""


# ---- 5. concurrent runs to one --out --------------------------------------------------------


def attack_concurrent(work: Path, rng: random.Random, quick: bool) -> Iterator[Attempt]:
    for k in range(1 if quick else 3):
        out = work / f"same-{k}"
        argv = [*HIL, "run", "--bench", "virtual-inprocess", "--duration", "20", "--no-plot",
                "--json", "--out", str(out)]  # fmt: skip
        if k == 2:
            argv.append("--overwrite")
        procs = [spawn(argv, work) for _ in range(3)]
        results = [finish(p) for p in procs]
        a = Attempt("concurrent", f"3 runs to one --out #{k}" + (" --overwrite" if k == 2 else ""))
        merge(a, [judge(Attempt("concurrent", ""), *r, want_json=True) for r in results])
        codes = [r[0] for r in results]
        # --overwrite: a run that starts after another ended may take its directory (asked for);
        # two may never record at once, which would leave a torn directory (checked below)
        if codes.count(0) != 1 and not (k == 2 and codes.count(0) >= 1):
            a.failures.append(f"{codes.count(0)} of 3 recorded (exits {codes})")
        check_run_dir(a, out)
        a.note = f"exits {codes} {a.note}".rstrip()
        yield a


# ---- main -----------------------------------------------------------------------------------

CATEGORIES = ("files", "options", "signals", "hub", "concurrent")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="a subset (for the slow test)")
    parser.add_argument("--seed", type=int, default=31)
    parser.add_argument("--only", choices=CATEGORIES, action="append", help="these categories")
    parser.add_argument("--json", action="store_true", help="every attempt as JSON on stdout")
    args = parser.parse_args(argv)
    rng = random.Random(args.seed)
    attempts: list[Attempt] = []
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="ddbench-attack-") as tmp:
        work = Path(tmp)
        gens = {
            "files": lambda: attack_files(work, rng, args.quick),
            "options": lambda: attack_options(work, rng, args.quick),
            "signals": lambda: attack_signals(work, rng, args.quick, work),
            "hub": lambda: attack_hub(work, rng, args.quick),
            "concurrent": lambda: attack_concurrent(work, rng, args.quick),
        }
        try:
            for cat in args.only or CATEGORIES:
                for a in gens[cat]():
                    attempts.append(a)
                    flag = "FAIL" if a.failed() else "ok  "
                    print(
                        f"{flag} {a.category:10} {a.name:40} exit={a.code} tb={_yn(a.traceback)} "
                        f"one-line={'yes' if a.one_line else 'no'} kept={_yn(a.data_kept)} "
                        f"json={_yn(a.json_ok)} robot={_yn(a.robot_ok)}  {a.note}"
                        + (f"  <- {'; '.join(a.failures)}" if a.failed() else ""),
                        file=sys.stderr,
                        flush=True,
                    )
        finally:
            for proc in list(_LIVE):
                reap(proc)
    summary = Counter((a.category, "failed" if a.failed() else "ok") for a in attempts)
    print(
        f"\n{len(attempts)} attempts in {time.monotonic() - t0:.0f} s (seed {args.seed})",
        file=sys.stderr,
    )
    for cat in dict.fromkeys(a.category for a in attempts):
        print(
            f"  {cat:10} {summary[(cat, 'ok')]:3} ok  {summary[(cat, 'failed')]:3} failed",
            file=sys.stderr,
        )
    if args.json:
        print(json.dumps([asdict(a) for a in attempts], indent=1))
    return 1 if any(a.failed() for a in attempts) else 0


def _yn(v: bool | None) -> str:
    return "-" if v is None else ("yes" if v else "no")


if __name__ == "__main__":
    sys.exit(main())
