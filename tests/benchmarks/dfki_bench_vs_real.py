"""The DFKI double pendulum on the bench beside the real one (issue 28 item 3).

The commanded torques of a real DFKI recording (`design A.0`, the lab's open-loop system
identification runs: kp = kd = 0, one torque command per period) are sent by the lab's own,
unmodified driver (mini-cheetah-motor-driver-socketcan, ``motor_driver.canmotorlib``) to the
`dfki-a0` robot on two virtual AK80-6 drives in MIT mode at the owners' CAN ids (the
`virtual-mit-inprocess` bench, lockstep, 2 ms). The bench's recording is written in the real
file's own layout (``--format dfki``: tau_con of row i acts from row i+1 on), so the real
recording and the simulated one differ only in what the model leaves out; then

    hil diagnose bench.csv --reference real.csv --robot dfki-a0 --format dfki

says what changed between them: simulation and reality, same commands, same protocol, side by
side. Also written: the positions of both (bench_vs_real.png) and one JSON document on stdout
(``--json``) or a summary.

    python tests/benchmarks/dfki_bench_vs_real.py [REAL.csv] --out DIR [--seconds S] [--json]

REAL defaults to the recording shipped in tests/data/dfki (BSD-3-Clause, its notice there);
any `trajectory.csv` of the shared DFKI data works (../shared/realdata/dfki-double-pendulum).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

TESTS = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(TESTS))

from mit_clients import run_dfki_driver  # noqa: E402  (tests/mit_clients.py)

from drivers.recording import dumps_strict  # noqa: E402
from hil.model.metrics import nrmse  # noqa: E402

SHIPPED = TESTS / "data" / "dfki" / "design_A.0__20220815__sys_id__trajectory_00.csv"
PERIOD_S = 0.002  # the bench's period (the DFKI loop's nominal 500 Hz)
LIMIT_NM = 6.0  # the lab's run_experiment clips its commands to the AK80-6's ±6 Nm
COLUMNS = ("time", "pos_meas1", "pos_meas2", "tau_con1", "tau_con2", "tau_meas1", "tau_meas2")
APART_RAD = 0.1  # the two motions are called apart once a joint differs by this much


def read_real(path: Path, seconds: float | None) -> dict[str, np.ndarray]:
    data = np.genfromtxt(path, delimiter=",", names=True)
    missing = [c for c in COLUMNS if c not in (data.dtype.names or ())]
    if missing:
        raise SystemExit(f"{path}: not a DFKI trajectory.csv (no column {', '.join(missing)})")
    rows = len(data) if seconds is None else min(len(data), round(seconds / PERIOD_S) + 1)
    return {c: np.asarray(data[c][:rows], dtype=float) for c in COLUMNS}


def bench_run(real: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Row k of the bench = row k of the real file: the real tau_con of row i acts from row
    i+1 on (profiles/formats/dfki.toml), the bench's command of period k from row k on, so
    period k sends tau_con[k-1]."""
    tau_con = np.clip(np.column_stack([real["tau_con1"], real["tau_con2"]]), -LIMIT_NM, LIMIT_NM)
    commands = np.vstack([np.zeros((1, 2)), tau_con[:-1]])
    undo: list[tuple[object, str, object]] = []

    def setattr_(obj: object, name: str, value: object) -> None:
        undo.append((obj, name, getattr(obj, name)))
        setattr(obj, name, value)

    try:  # the driver prints its progress on stdout: sent to stderr, stdout is the result's
        with contextlib.redirect_stdout(sys.stderr):
            got, _, server = run_dfki_driver(setattr_, "dfki-bench-vs-real", commands)
    finally:
        for obj, name, value in reversed(undo):
            setattr(obj, name, value)
    if server.ignored or server.errors:
        raise SystemExit(
            f"the virtual drives ignored {server.ignored} frames, {server.errors} errors"
        )
    n = len(commands)
    reply_tau = got[:, [2, 5]]
    return {
        "time": np.arange(n) * PERIOD_S,
        "pos_meas1": got[:, 0],
        "pos_meas2": got[:, 3],
        "tau_con1": tau_con[:, 0],  # stored as the real file stores it (acts from row i+1)
        "tau_con2": tau_con[:, 1],
        # tau_meas of row i is the torque that acted up to row i (loop delay −1)
        "tau_meas1": np.concatenate([[0.0], reply_tau[:-1, 0]]),
        "tau_meas2": np.concatenate([[0.0], reply_tau[:-1, 1]]),
    }


def write_csv(path: Path, columns: dict[str, np.ndarray]) -> None:
    table = np.column_stack([columns[c] for c in COLUMNS])
    np.savetxt(path, table, delimiter=",", header=",".join(COLUMNS), comments="", fmt="%.12g")


def plot(path: Path, real: dict[str, np.ndarray], bench: dict[str, np.ndarray]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 1, sharex=True, figsize=(9, 5.5))
    for j, ax in enumerate(axes, start=1):
        ax.plot(real["time"], real[f"pos_meas{j}"], label="real (DFKI)", lw=1.2)
        ax.plot(
            bench["time"], bench[f"pos_meas{j}"], "--", label="bench (dfki-a0, MIT mode)", lw=1.2
        )
        ax.set_ylabel(f"q{j} (rad)")
        ax.grid(alpha=0.3)
    axes[0].legend(loc="best")
    axes[0].set_title("Same commands through the DFKI driver: real arm and virtual bench")
    axes[-1].set_xlabel("t (s)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("real", nargs="?", type=Path, default=SHIPPED, help="a DFKI trajectory.csv")
    ap.add_argument("--out", type=Path, required=True, help="directory to write (made if absent)")
    ap.add_argument("--seconds", type=float, default=None, help="only the first S seconds")
    ap.add_argument("--json", action="store_true", help="one JSON document on stdout")
    args = ap.parse_args(argv)
    if args.seconds is not None and not args.seconds > 0.5:
        ap.error("--seconds must be > 0.5")
    if not args.real.is_file():
        ap.error(f"{args.real}: no such file")
    args.out.mkdir(parents=True, exist_ok=True)

    real = read_real(args.real, args.seconds)
    bench = bench_run(real)
    real_csv, bench_csv = args.out / "real.csv", args.out / "bench.csv"
    write_csv(real_csv, real)
    write_csv(bench_csv, bench)
    plot(args.out / "bench_vs_real.png", real, bench)

    dq = np.abs(
        np.column_stack(
            [bench["pos_meas1"] - real["pos_meas1"], bench["pos_meas2"] - real["pos_meas2"]]
        )
    )
    apart = np.flatnonzero(dq.max(axis=1) > APART_RAD)
    positions = {
        "nrmse": [float(nrmse(real[f"pos_meas{j}"], bench[f"pos_meas{j}"])) for j in (1, 2)],
        "max_abs_rad": [float(x) for x in dq.max(axis=0)],
        "apart_after_s": float(real["time"][apart[0]] - real["time"][0]) if apart.size else None,
    }
    cmd = [
        sys.executable,
        "-m",
        "hil.cli",
        "diagnose",
        str(bench_csv),
        "--reference",
        str(real_csv),
        "--robot",
        "dfki-a0",
        "--format",
        "dfki",
        "--out",
        str(args.out / "diagnosis"),
        "--overwrite",
        "--json",
        "--no-plot",
    ]
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if proc.returncode not in (0, 1):
        sys.stderr.write(proc.stderr)
        raise SystemExit(f"hil diagnose exited {proc.returncode}")
    report = json.loads(proc.stdout)
    doc = {
        "real": args.real.name,
        "rows": len(real["time"]),
        "seconds": float(real["time"][-1] - real["time"][0]),
        "positions": positions,
        "diagnose": {"command": " ".join(["hil", *cmd[3:]]), "exit": proc.returncode},
        "findings": report.get("findings", []),
        "drift": report.get("nominal", {}).get("drift", report.get("nominal")),
        "summary": report.get("summary"),
        "out": str(args.out),
    }
    if args.json:
        print(dumps_strict(doc, indent=2))
    else:
        print(
            f"{doc['real']}: {doc['rows']} rows, {doc['seconds']:.2f} s, "
            "commands through the DFKI driver"
        )
        print(
            "positions, bench vs real: NRMSE "
            + ", ".join(f"{x:.1%}" for x in positions["nrmse"])
            + f"; apart by {APART_RAD} rad after "
            + (
                f"{positions['apart_after_s']:.2f} s"
                if positions["apart_after_s"] is not None
                else "never"
            )
        )
        print(f"diagnosis (bench against the real recording): {doc['summary']}")
        print(f"written: {args.out}/bench.csv, real.csv, bench_vs_real.png, diagnosis/")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
