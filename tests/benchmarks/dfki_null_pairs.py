"""Nulls of another motion: every ordered pair of the DFKI system-identification recordings of
one design, the recording judged with ``--reference`` the other (the same arm, nothing written
in), through the drift stage as `hil diagnose` runs it. Every drift finding is a false one.

    python tests/benchmarks/dfki_null_pairs.py [--robot dfki-c0] [--glob 'design_C.0*sys_id*']
        [--references K]

``--references K`` (K ≥ 2): each recording judged once, against the K recordings that follow
it (in name order, cyclically) together, as a user with several recordings of the arm would
(the change must then also stand out of the references' spread: docs/diagnosis.md, gate 5).

Reads ../shared/realdata/dfki-double-pendulum/records (tests/realdata.py); prints one line per
pair (whether the reference model was used, the findings) and the totals.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from realdata import realdata

from hil.cli_options import read_recording
from hil.diagnose.cli import add_arguments, arm_geometry
from hil.diagnose.drift import judge, nominal_from_reference
from hil.model.closed_form import ArmModel
from hil.model.params import robot_params

DESIGN_GLOB = {"dfki-a0": "design_A.0*sys_id*.csv", "dfki-c0": "design_C.0*sys_id*.csv"}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robot", default="dfki-c0", choices=sorted(DESIGN_GLOB))
    ap.add_argument("--glob", default=None, help="recordings of the design (default: its sys_id)")
    ap.add_argument("--references", type=int, default=1, help="references per judgement (K)")
    opts = ap.parse_args(argv)
    records = realdata("dfki-double-pendulum") / "records"
    files = sorted(records.glob(opts.glob or DESIGN_GLOB[opts.robot]))
    if len(files) < 2:
        print(f"fewer than two recordings under {records}", file=sys.stderr)
        return 2
    p = argparse.ArgumentParser()
    add_arguments(p)
    args = p.parse_args([str(files[0]), "--format", "dfki", "--robot", opts.robot])
    model, geometry = ArmModel(robot_params(opts.robot).terms), arm_geometry(opts.robot)

    def read(path: Path):
        with contextlib.redirect_stderr(io.StringIO()):  # the readers' notes
            return read_recording(
                args, path, command="diagnose", min_rows=2, joints=2, allow_gaps=True
            )

    recs = {f: read(f) for f in files}
    pairs = used = wrong = 0

    def one(rec: Path, refs: list[Path], nominal) -> None:
        nonlocal pairs, used, wrong
        started = time.perf_counter()
        result = judge([recs[rec]], nominal)
        keys = [f.term or f.effect for f in result.findings]
        pairs, used, wrong = pairs + 1, used + result.used, wrong + bool(keys)
        names = " + ".join(r.stem[-24:] for r in refs)
        print(
            f"{rec.stem[-24:]:>24} against {names:>24}: "
            f"{'used' if result.used else 'not used'}, findings {keys or 'none'} "
            f"({time.perf_counter() - started:.0f} s)",
            flush=True,
        )

    if opts.references > 1:
        if opts.references >= len(files):
            print(f"--references must be under {len(files)}", file=sys.stderr)
            return 2
        for i, rec in enumerate(files):
            refs = [files[(i + k) % len(files)] for k in range(1, opts.references + 1)]
            nominal = nominal_from_reference(
                [recs[r] for r in refs], model, "null", geometry=geometry
            )
            one(rec, refs, nominal)
    else:
        for ref in files:
            nominal = nominal_from_reference([recs[ref]], model, "null pair", geometry=geometry)
            for rec in files:
                if rec != ref:
                    one(rec, [ref], nominal)
    print(f"{pairs} judgements, reference model used on {used}, a false finding on {wrong}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
