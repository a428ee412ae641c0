"""How long each pty write waits for the kernel worker that delivers it, and who held the CPUs.

A write to a pty queues the tty flip buffer's work (``flush_to_ldisc``) on an unbound kernel
workqueue; a kworker at normal priority runs it and only then can the reader wake
(docs/jitter.md, "Beside CPU-bound jobs"). This records, system-wide with ``perf``, every
``workqueue_queue_work`` / ``workqueue_execute_start`` of ``flush_to_ldisc`` and every context
switch for ``--seconds``, while ``COMMAND`` runs (or whatever else is running: start a
``hil jitter`` beside it), and reports

* the *hop* delay, queued → the worker starts it: median, p99, max, how many over 5 / 20 ms;
* for the longest hops, what ran on each CPU meanwhile (name, pid, kernel priority: 120 is
  nice 0, 89 is SCHED_FIFO 10, the priority ``hil`` gives its loop and the virtual robot);
* every realtime thread (kernel priority < 100) that ran longer than 5 ms without a break,
  with its process's command line: such a thread holds its CPU against every normal task,
  the pty's worker among them;
* the steal time of each CPU meanwhile (/proc/stat): time the hypervisor did not run the
  vCPU, which the trace shows as the current task running.

    python tests/benchmarks/pty_hops.py [--seconds 15] [--top 5] [--json] [-- COMMAND ...]

Needs ``perf`` and the right to trace (root, or ``perf_event_paranoid`` ≤ -1).
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

EVENTS = (
    "workqueue:workqueue_queue_work",
    "workqueue:workqueue_execute_start",
    "sched:sched_switch",
)
_LINE = re.compile(r"^\s*(\d+)/(\d+)\s+\[(\d+)\]\s+([\d.]+):\s+(\S+):\s*(.*)$")
_SWITCH = re.compile(
    r"prev_comm=(.*?) prev_pid=(\d+) prev_prio=(\d+) prev_state=(\S+) ==> "
    r"next_comm=(.*?) next_pid=(\d+) next_prio=(\d+)"
)
_WORK = re.compile(r"work struct[= ](0x[0-9a-f]+)")
LONG_RT_RUN_S = 0.005


def _command_lines(stop: threading.Event, into: dict[int, str]) -> None:
    """pid → command line of every process seen while recording (they may be gone after)."""
    while True:
        for entry in Path("/proc").iterdir():
            if entry.name.isdigit() and int(entry.name) not in into:
                try:
                    raw = (entry / "cmdline").read_bytes()
                except OSError:
                    continue
                into[int(entry.name)] = raw.replace(b"\0", b" ").decode(errors="replace")[:160]
        if stop.wait(0.5):
            return


def steal_s() -> dict[str, float]:
    """Seconds each CPU's vCPU was not run by the hypervisor (/proc/stat "steal") since boot."""
    hz = os.sysconf("SC_CLK_TCK")
    out = {}
    for line in Path("/proc/stat").read_text().splitlines():
        f = line.split()
        if f[0].startswith("cpu") and f[0] != "cpu" and len(f) > 8:
            out[f[0]] = int(f[8]) / hz
    return out


def record(seconds: float, data: Path, command: list[str]) -> dict[int, str]:
    events = [a for e in EVENTS for a in ("-e", e)]
    cmdlines: dict[int, str] = {}
    stop = threading.Event()
    watcher = threading.Thread(target=_command_lines, args=(stop, cmdlines), daemon=True)
    watcher.start()
    perf = subprocess.Popen(
        [
            "perf",
            "record",
            "-q",
            "-a",
            "--no-buildid",
            "--no-buildid-cache",
            *events,
            "-o",
            str(data),
            "--",
            "sleep",
            str(seconds),
        ],
        stderr=subprocess.PIPE,
        text=True,
    )
    child = subprocess.Popen(command) if command else None
    try:
        _, err = perf.communicate()
    finally:
        if child is not None:
            child.wait()
        stop.set()
        watcher.join()
    if perf.returncode != 0:
        raise SystemExit(f"pty_hops: perf record failed: {' '.join(err.split())[:300]}")
    return cmdlines


def analyse(data: Path, cmdlines: dict[int, str], top: int) -> dict[str, Any]:
    text = subprocess.run(
        ["perf", "script", "-i", str(data), "-F", "pid,tid,cpu,time,event,trace"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    queued: dict[str, tuple[float, int, int]] = {}
    hops: list[tuple[float, float, float, int, int, int]] = []  # delay, t_q, t_run, pid, cpus
    switches: dict[int, list[tuple[float, str, int, int, str, int, int]]] = collections.defaultdict(
        list
    )
    process_of: dict[int, int] = {}
    rt_since: dict[int, tuple[float, int]] = {}
    rt_runs: list[dict[str, Any]] = []
    for line in text.splitlines():
        m = _LINE.match(line)
        if m is None:
            continue
        pid, tid, cpu, t = int(m[1]), int(m[2]), int(m[3]), float(m[4])
        event, rest = m[5], m[6]
        process_of[tid] = pid
        if event.endswith("sched_switch"):
            s = _SWITCH.search(rest)
            if s is None:
                continue
            prev, next_ = int(s[2]), int(s[6])
            switches[cpu].append((t, s[1], prev, int(s[3]), s[4], next_, int(s[7])))
            if prev in rt_since:
                start, _ = rt_since.pop(prev)
                if t - start > LONG_RT_RUN_S:
                    owner = process_of.get(prev, prev)
                    rt_runs.append(
                        {
                            "ms": round((t - start) * 1e3, 2),
                            "at_s": start,
                            "tid": prev,
                            "pid": owner,
                            "cpu": cpu,
                            "then": s[4],
                            "command": cmdlines.get(owner, "?"),
                        }
                    )
            if int(s[7]) < 100:
                rt_since[next_] = (t, cpu)
        elif "flush_to_ldisc" in rest:
            w = _WORK.search(rest)
            if w is None:
                continue
            if event.endswith("workqueue_queue_work"):
                queued.setdefault(w[1], (t, pid, cpu))
            elif event.endswith("workqueue_execute_start") and w[1] in queued:
                tq, qpid, qcpu = queued.pop(w[1])
                hops.append((t - tq, tq, t, qpid, qcpu, cpu))
    if not hops:
        return {"hops": 0, "note": "no pty writes while recording"}
    d = np.array([h[0] for h in hops]) * 1e3
    worst = []
    for delay, tq, tr, qpid, qcpu, _run_cpu in sorted(hops, reverse=True)[:top]:
        held = {}
        for cpu, sw in sorted(switches.items()):
            ran: collections.Counter[tuple[str, int, int]] = collections.Counter()
            current, since = None, tq
            for t, pcomm, ppid, pprio, _state, npid, nprio in sw:
                if t < tq:
                    current = (npid, nprio)
                    continue
                if t > tr:
                    break
                ran[(pcomm, process_of.get(ppid, ppid), pprio)] += t - max(since, tq)
                current, since = (npid, nprio), t
            if current is not None:
                ran[("?", process_of.get(current[0], current[0]), current[1])] += tr - since
            held[f"cpu{cpu}"] = [
                {"comm": c, "pid": p, "prio": pr, "ms": round(dt * 1e3, 2)}
                for (c, p, pr), dt in ran.most_common(4)
                if dt > 0
            ]
        worst.append(
            {
                "ms": round(delay * 1e3, 2),
                "at_s": tq,
                "writer_pid": qpid,
                "writer": cmdlines.get(qpid, "?"),
                "queued_on": qcpu,
                "held": held,
            }
        )
    rt_runs.sort(key=lambda r: -r["ms"])
    return {
        "hops": len(hops),
        "hop_ms": {
            "median": float(np.median(d)),
            "p99": float(np.percentile(d, 99)),
            "p999": float(np.percentile(d, 99.9)),
            "max": float(d.max()),
            "over_5ms": int((d > 5).sum()),
            "over_20ms": int((d > 20).sum()),
        },
        "longest_hops": worst,
        "realtime_runs_over_5ms": rt_runs[:20],
        "load_average": os.getloadavg()[0],
    }


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seconds", type=float, default=15.0)
    p.add_argument("--top", type=int, default=5, help="longest hops to explain")
    p.add_argument("--json", action="store_true")
    p.add_argument("command", nargs=argparse.REMAINDER, help="-- COMMAND to run meanwhile")
    args = p.parse_args()
    command = args.command[1:] if args.command[:1] == ["--"] else args.command
    if shutil.which("perf") is None:
        print("pty_hops: perf is not installed (linux-tools / linux-perf)", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory() as tmp:
        data = Path(tmp) / "perf.data"
        started = time.strftime("%H:%M:%S")
        stolen = steal_s()
        cmdlines = record(args.seconds, data, command)
        stolen = {cpu: round(s - stolen.get(cpu, 0.0), 3) for cpu, s in steal_s().items()}
        report = analyse(data, cmdlines, args.top)
    report["recorded_from"] = started
    report["steal_s"] = stolen  # time the hypervisor did not run each vCPU meanwhile
    if args.json:
        print(json.dumps(report, indent=1))
        return 0
    if not report["hops"]:
        print(report["note"])
        return 0
    h = report["hop_ms"]
    print(
        f"{report['hops']} pty hops in {args.seconds:g} s from {started} (load "
        f"{report['load_average']:.1f}): queued → run median {h['median'] * 1e3:.0f} µs, p99 "
        f"{h['p99']:.2f} ms, p99.9 {h['p999']:.2f} ms, max {h['max']:.1f} ms; "
        f"{h['over_5ms']} over 5 ms, {h['over_20ms']} over 20 ms; steal (vCPU not run) "
        + ", ".join(f"{cpu} {s * 1e3:.0f} ms" for cpu, s in report["steal_s"].items())
    )
    for w in report["longest_hops"]:
        print(f"\nhop of {w['ms']:.1f} ms, written by pid {w['writer_pid']} ({w['writer'][:80]})")
        for cpu, ran in w["held"].items():
            who = ", ".join(
                f"{r['comm']}:{r['pid']} prio {r['prio']} {r['ms']:.1f} ms" for r in ran
            )
            print(f"  {cpu} meanwhile: {who}")
    runs = report["realtime_runs_over_5ms"]
    print(f"\nrealtime threads that ran > 5 ms without a break: {len(runs)}")
    for r in runs[:10]:
        print(
            f"  {r['ms']:.1f} ms on cpu{r['cpu']}, tid {r['tid']} of pid {r['pid']} "
            f"({r['command'][:90]}), then {r['then']}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
