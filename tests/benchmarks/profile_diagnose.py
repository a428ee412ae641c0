"""Profile one `hil diagnose` of a recording: CPU time and resident memory at every stage, the
stack where the resident size peaked, optionally cProfile, and the document as JSON.

    python tests/benchmarks/profile_diagnose.py RUN_DIR OUT_PREFIX [--cprofile] [--tracemalloc]

Writes OUT_PREFIX.json (the document without its timing, to compare two trees field by field)
and with ``--cprofile`` OUT_PREFIX.prof (``python -m pstats``); ``--tracemalloc`` also prints
the live (traced) memory at every stage, against the resident size (several times slower). Runs
with one BLAS thread, as
every ``hil`` command does. The stack is sampled every 20 ms from a thread, so the peak it names
is the nearest sample's. Used for docs/diagnosis.md, "Memory and long recordings".
"""

from __future__ import annotations

import argparse
import cProfile
import json
import resource
import sys
import threading
import time
import traceback
import tracemalloc
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from drivers.process import limit_blas_threads


def resident_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * resource.getpagesize() / 1e6


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("recording", help="run directory or CSV")
    ap.add_argument("out", help="output prefix: OUT.json, OUT.prof")
    ap.add_argument("--cprofile", action="store_true", help="also write OUT.prof")
    ap.add_argument("--tracemalloc", action="store_true", help="also print the live memory")
    args = ap.parse_args()
    limit_blas_threads()
    from drivers.recording import read_signals
    from hil.diagnose.pipeline import diagnose
    from hil.model.params import robot_params

    peak = {"mb": 0.0, "stack": ""}
    main_id = threading.main_thread().ident
    done = threading.Event()

    def sample() -> None:
        while not done.wait(0.02):
            mb = resident_mb()
            if mb > peak["mb"]:
                frame = sys._current_frames().get(main_id)
                peak["mb"] = mb
                peak["stack"] = "".join(traceback.format_stack(frame)[-6:]) if frame else ""

    def say(message: str) -> None:
        maxrss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e3
        live = ""
        if tracemalloc.is_tracing():
            live = f"live {tracemalloc.get_traced_memory()[0] / 1e6:5.0f} MB, "
        print(
            f"[{time.process_time():6.1f} s CPU] {live}resident {resident_mb():5.0f} MB, "
            f"peak {maxrss:5.0f} MB: {message}",
            flush=True,
        )

    if args.tracemalloc:
        tracemalloc.start()

    threading.Thread(target=sample, daemon=True).start()
    rec = read_signals(args.recording)
    say(f"read {len(rec)} rows")
    profile = cProfile.Profile() if args.cprofile else None
    if profile:
        profile.enable()
    doc = diagnose([rec], robot_params("cicese").theta, progress=say).document
    if profile:
        profile.disable()
        profile.dump_stats(f"{args.out}.prof")
    done.set()
    say("done")
    doc.pop("timing_s", None)
    Path(f"{args.out}.json").write_text(json.dumps(doc, indent=1) + "\n")
    print(f"resident peak sampled {peak['mb']:.0f} MB at:\n{peak['stack']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
