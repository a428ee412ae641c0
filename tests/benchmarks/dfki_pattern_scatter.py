"""How far one drift pattern moves with the motion on an unchanged arm: for every DFKI
system-identification recording of a design, the pattern fitted together with θ on that
recording alone (Gauss–Newton on its linearisation point, θ refitted each step), with its
blocked-bootstrap SE. Two recordings' values differ by what the model's error projects onto the
pattern under each motion; where that spread exceeds the SEs, an unpaired comparison
(`hil diagnose REC --reference OTHER`) can name a change that is not one
(docs/real-data-diagnosis.md, "Unpaired comparisons").

    python tests/benchmarks/dfki_pattern_scatter.py [--robot dfki-a0] [--effect encoder_offset]

Reads ../shared/realdata/dfki-double-pendulum/records (tests/realdata.py); prints one line per
recording (the pattern's size on each joint) and, per joint, the spread over the recordings
against the median SE.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from realdata import realdata

from hil.cli_options import read_recording
from hil.diagnose.cli import add_arguments, arm_geometry
from hil.diagnose.drift.fit import make_fit
from hil.diagnose.drift.judge import problem_inputs
from hil.diagnose.drift.terms import Term
from hil.diagnose.effects import REGISTRY
from hil.diagnose.physical import bounded_fit
from hil.diagnose.problem import build_problem
from hil.model.closed_form import ArmModel
from hil.model.params import robot_params

DESIGN_GLOB = {"dfki-a0": "design_A.0*sys_id*.csv", "dfki-c0": "design_C.0*sys_id*.csv"}
STEPS = 4  # Gauss–Newton steps of the linearisation point
DRAWS = 100


def own_size(prob, model, effect, joint: int, geometry) -> tuple[float, float]:
    """The pattern's size and SE with θ refitted together with it on ``prob``'s rows."""
    theta, _ = bounded_fit(prob, model, None, prob.y, 0)
    p, at, out = model.n_params, None, (np.nan, np.nan)
    for _ in range(STEPS if effect.nonlinear else 1):
        fit = make_fit(prob, model, theta, geometry=geometry)
        at = effect.start(fit.ctx, joint) if at is None else at
        term = fit.build(Term(effect, joint, at))
        target = (prob.y_raw - (0.0 if term.shift is None else term.shift)) / prob.scale
        both, boot = bounded_fit(prob, model, term.cols / prob.scale[None, :, None], target, DRAWS)
        beta, se, theta = both[p:], boot[:, p:].std(axis=0), both[:p]
        out = effect.estimate(fit.ctx, joint, beta, se, at)[1:]
        at = effect.update(fit.ctx, joint, beta, at)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robot", default="dfki-a0", choices=sorted(DESIGN_GLOB))
    ap.add_argument("--effect", default="encoder_offset", choices=sorted(REGISTRY))
    opts = ap.parse_args(argv)
    records = realdata("dfki-double-pendulum") / "records"
    files = sorted(records.glob(DESIGN_GLOB[opts.robot]))
    if not files:
        print(f"no recordings under {records}", file=sys.stderr)
        return 2
    p = argparse.ArgumentParser()
    add_arguments(p)
    args = p.parse_args([str(files[0]), "--format", "dfki", "--robot", opts.robot])
    model, geometry = ArmModel(robot_params(opts.robot).terms), arm_geometry(opts.robot)
    effect = REGISTRY[opts.effect]
    sizes = []
    for f in files:
        with contextlib.redirect_stderr(io.StringIO()):  # the readers' notes
            rec = read_recording(args, f, command="diagnose", min_rows=2, joints=2, allow_gaps=True)
        prob, _ = build_problem(problem_inputs([rec]), model)
        row = [own_size(prob, model, effect, j, geometry) for j in range(2)]
        sizes.append(row)
        cells = "  ".join(f"joint {j + 1}: {s:+.4g} ± {e:.2g}" for j, (s, e) in enumerate(row))
        print(f"{f.stem[-30:]:>30}  {cells}", flush=True)
    a = np.array(sizes)  # (recordings, joints, 2)
    for j in range(2):
        print(
            f"joint {j + 1}: spread (SD) over {len(files)} recordings "
            f"{a[:, j, 0].std(ddof=1):.3g}, median SE {np.median(a[:, j, 1]):.3g}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
