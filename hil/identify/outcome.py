"""What the three paths of `hil identify` (:mod:`hil.identify.pipelines`) share: their result
(:class:`Outcome`: the report, the text, the parameter files to write) and the run of an
experiment over a bench that each records from (:func:`record_run`, feeding the online RLS).
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from drivers.arm import Sample
from drivers.realtime_times import COMPUTE_S, HostStampRows
from drivers.recording import Recording
from hil.cli_options import (
    drive_kwargs,
    read_recording,
    require_complete,
    say,
)
from hil.identify.online import OnlineIdentifier

PAPER_LAMBDA_NOTE = (
    'the paper\'s "λ = 50 Hz" is read as λ = 50 rad/s in f(s) = λ/(s + λ) (about twice its '
    "highest excitation frequency, 26 rad/s); --lambda 314.16 is the 2π·50 rad/s reading"
)


@dataclass
class Outcome:
    """What a path of `hil identify` made: the JSON report (identify.json, --json), the text to
    print, and the parameter files to write: ``(path, schemes, options)`` each, written by
    :func:`hil.model.params.save_params` ``(path, schemes, **options)``."""

    report: dict[str, Any]
    text: str
    params: list[tuple[Path, dict[str, dict[str, Any]], dict[str, Any]]] = field(
        default_factory=list
    )


PAPER_EXCITATION, PAPER_VALIDATION = "reyes-kelly", "validation-multisine"


def arm_experiment(robot: str, kind: str, paper: str) -> str:
    """The default experiment of ``kind`` (excitation, validation) over a bench with ``robot``:
    the arm's own ``<robot>-<kind>`` profile where one is shipped (designed by `hil excite
    --bench` within that bench's limits), else ``paper`` (Reyes & Kelly's, for the CICESE arm:
    its torques, up to 97 Nm, drive a lighter arm far past its velocity limits)."""
    from profiles import ProfileError, resolve

    own = f"{Path(robot).stem}-{kind}"
    try:
        resolve("experiments", own)
    except ProfileError:
        return paper
    return own


def record_run(
    args: argparse.Namespace,
    bench: str,
    experiment: str,
    out: Path,
    online: OnlineIdentifier | None,
    robot: str | None = None,
) -> Recording:
    """Run ``experiment`` over ``bench`` (with ``robot`` in place of the bench's arm if given)
    into ``out``, feeding ``online`` as it runs; the recording."""
    from hil.bench.run import run_experiment
    from profiles.bench import load_bench

    last: dict[str, Any] = {"late_s": 0.0}
    realtime = (getattr(args, "mode", None) or load_bench(bench).mode) == "realtime"
    # realtime: the rows on the host's stamps as they come (what is known online; the robot's
    # own clock, robot-events.csv, is read after the run); lockstep: every interval is h
    stamps = HostStampRows(COMPUTE_S["hil run"]) if online is not None and realtime else None

    def observer(k: int, sample: Sample) -> None:
        # sample k: q_k and the quantized torque of period k − 1, so row k − 1 is complete now
        started = time.perf_counter()
        if stamps is not None:
            row = stamps.push(sample.sent_at, sample.received_at, sample.tau_Nm, last["late_s"])
            if row is not None:
                assert online is not None
                online.push(last["q"], row.tau, t=row.t, uncertainty_s=row.uncertainty_s)
        elif online is not None and k > 0:
            online.push(last["q"], sample.tau_Nm)
        last["q"] = sample.q_rad
        # this cycle's command goes out after the update: it acts that much later
        last["late_s"] = time.perf_counter() - started

    say("identify", f"running {experiment} over {bench} -> {out}")
    run = run_experiment(
        bench,
        experiment,
        out,
        duration_s=args.duration,
        **drive_kwargs(args),
        progress=not args.json,
        observer=observer,
        robot=robot,
    )
    require_complete(f"{experiment} over {bench}", run)
    # as `hil identify --from OUT` reads it: a realtime run on its real times
    joints = 2 if robot is None else None  # an arm named by --robot: its own joint count
    rec = read_recording(args, out, command="identify", min_rows=2, joints=joints, allow_gaps=True)
    if online is not None:  # the last row's torque is only in the recording; its own command
        online.push(rec.q[-1], rec.tau[-1], t=None if stamps is None else stamps.newest_s)
    return rec
