"""The online RLS and the paper discretization of a realtime run with stalls, before and after
they read the run on its real sample times (issue 12 item 1): the table of
docs/identification.md, "Realtime runs: online and paper on real times".

    python tests/benchmarks/realtime_online.py [--duration 20] [--out DIR] [--run DIR]

Runs `hil identify --bench virtual-slcan --mode realtime --duration D --json --no-plot
--validation-experiment none --out DIR` (or reads the report of an earlier one with ``--run``)
and prints, per scheme, the largest relative error of θ1..θ5 and of θ6..θ9 against the cicese
profile (the virtual robot's θ) for:

* offline: the batch fit after the run, on the robot's clock (robot-events.csv);
* online (now): the report's online θ̂, each row on the host's stamps as they came;
* online on k·h (before): the same run's rows pushed on the deadline grid, as the online RLS
  did before (the recording's q and torque, k·h, every row);
* online replayed on the host's stamps, every row / with the bracket rule: the recording's
  stamps (sync_sent_s, feedback_s) through HostStampRows and OnlineIdentifier after the run,
  without the update's own time (not recorded), taking every row, or leaving out the rows on
  loosely bracketed stamps as the online RLS does;
* paper on k·h (before) and paper per interval (now): the batch fit with the paper's
  discretization on the run read on its real times, its formulas on k·h / over each interval.

The run is realtime on a shared machine: every rerun has other stalls and other numbers.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from drivers.realtime_times import COMPUTE_S, HostStampRows
from drivers.recording import read_signals
from hil.cli_options import read_recording
from hil.identify.online import OnlineIdentifier
from hil.identify.schemes import identify, irregular_times
from hil.model.regressors import SCHEMES

READER = argparse.Namespace(columns=None, loop_delay=None, torque=None, recording_format=None)


def _errors(theta: np.ndarray, reference: np.ndarray) -> str:
    e = 100 * np.abs((np.asarray(theta) - reference) / reference)
    return f"{e[:5].max():7.1f} {e[5:].max():8.1f}"


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--duration", type=float, default=20.0)
    p.add_argument("--out", help="where the run goes (default: a temporary directory)")
    p.add_argument("--run", help="the --out of an earlier `hil identify --bench` run: read it")
    args = p.parse_args()
    if args.run:
        out = Path(args.run)
        report = json.loads((out / "identify.json").read_text())
    else:
        out = Path(args.out or tempfile.mkdtemp(prefix="realtime-online-"))
        done = subprocess.run(
            [sys.executable, "-m", "hil.cli", "identify", "--bench", "virtual-slcan", "--mode",
             "realtime", "--duration", str(args.duration), "--json", "--no-plot",
             "--validation-experiment", "none", "--out", str(out), "--overwrite"],
            capture_output=True, text=True, timeout=1800,
        )  # fmt: skip
        if done.returncode != 0:
            print(done.stderr, file=sys.stderr)
            return done.returncode
        report = json.loads(done.stdout)
    reference = np.array(report["reference"]["theta"])
    online = report["online"]
    raw = read_signals(out / "fit")
    grid = OnlineIdentifier(raw.period_s)
    for q, tau in zip(raw.q, raw.tau, strict=True):
        grid.push(q, tau)
    replayed = {"every row": OnlineIdentifier(raw.period_s), "bracket rule": OnlineIdentifier(
        raw.period_s)}  # fmt: skip
    stamps = HostStampRows(COMPUTE_S["hil run"])
    sent, received = raw.columns["sync_sent_s"], raw.columns["feedback_s"]
    for k in range(len(raw)):
        row = stamps.push(sent[k], received[k], raw.tau[k - 1] if k else raw.tau[0])
        if row is not None:
            replayed["every row"].push(raw.q[k - 1], row.tau, row.t)
            replayed["bracket rule"].push(raw.q[k - 1], row.tau, row.t, row.uncertainty_s)
    for online_fit in replayed.values():
        online_fit.push(raw.q[-1], raw.tau[-1], stamps.newest_s)
    rec = read_recording(READER, out / "fit", command="realtime_online", allow_gaps=True)
    times = irregular_times(rec)
    paper = {
        label: identify(
            rec.q, rec.tau, rec.period_s, discretization="paper", t=t, segments=rec.segments()
        )
        for label, t in (("before", None), ("now", times))
    }
    print(
        f"run {out / 'fit'}: {online['samples']} samples, {len(rec.segments())} segment(s); "
        f"online rows left out (a sample time not known to within "
        f"{online['stamp_uncertainty_max_s'] * 1e3:.3g} ms): "
        f"{online['rows_left_out_uncertain_times']} (replayed: "
        f"{replayed['bracket rule'].rows_uncertain})"
    )
    print("largest |relative error| in %, θ1..θ5 / θ6..θ9, against the cicese profile")
    print(f"{'':38s}" + "".join(f"{s:>18s}" for s in SCHEMES))
    lines = {
        "offline, robot's clock": {
            s: report["discretizations"]["exact"]["schemes"][s]["theta_rls"] for s in SCHEMES
        },
        "online, host stamps (now)": online["theta"],
        "online, deadline grid (before)": grid.theta,
        "replayed, host stamps, every row": replayed["every row"].theta,
        "replayed, host stamps, bracket rule": replayed["bracket rule"].theta,
        "paper, k·h (before)": {s: paper["before"][s].theta_rls for s in SCHEMES},
        "paper, per interval (now)": {s: paper["now"][s].theta_rls for s in SCHEMES},
    }
    for label, thetas in lines.items():
        print(f"{label:38s}" + "".join(f"{_errors(thetas[s], reference):>18s}" for s in SCHEMES))
    return 0


if __name__ == "__main__":
    sys.exit(main())
