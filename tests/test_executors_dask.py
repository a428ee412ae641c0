"""Sweeps on Dask (issue 17): `hil jitter --sweep --executor dask` gives the serial executor's
JSON byte for byte; a worker killed mid-sweep loses only its point, which is retried once and
then reported with its parameters; a missing extra or an absent scheduler is a one-line error.

The LocalCluster tests need the `dask` extra (`make test` installs it) and take ~30-60 s on
a loaded 2-core machine; the own-cluster and diagnosis-set checks are `slow`.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import sys
from collections.abc import Callable, Iterable, Iterator
from functools import partial
from pathlib import Path
from typing import Any

import pytest

from hil import cli
from hil.bench.executors import MISSING_DASK, SerialExecutor, make_executor
from hil.bench.jobs import ExecutorUnavailableError, Outcome, TaskFailedError
from hil.timing.sweep import PointSpec, add_sweep_arguments, reproducible, run_point, sweep

# one worker runs the whole module under `pytest -n` (`--dist loadgroup`): its module
# fixtures are built once, not once per worker
pytestmark = pytest.mark.xdist_group("executors_dask")

BATCH_TIMEOUT_S = 180.0  # a hung cluster fails the test instead of blocking `make test`


def sweep_args(out: Path, spec: str, *extra: str) -> Any:
    import argparse

    p = argparse.ArgumentParser()
    p.add_argument("--bench", default="virtual-inprocess")
    p.add_argument("--out", default=None)
    p.add_argument("--no-plot", action="store_true")
    add_sweep_arguments(p)
    return p.parse_args(["--sweep", spec, "--out", str(out), "--no-plot", *extra])


@pytest.fixture(scope="module")
def dask_client() -> Iterator[Any]:
    """2 worker processes, one thread each, the scheduler's stock settings (allowed-failures
    3, as on a cluster someone else runs); closed after the module."""
    distributed = pytest.importorskip("distributed")
    cluster = distributed.LocalCluster(
        n_workers=2,
        threads_per_worker=1,
        processes=True,
        host="127.0.0.1",
        dashboard_address=None,
        scheduler_kwargs={"dashboard_address": "127.0.0.1:0"},
    )
    client = distributed.Client(cluster, timeout=60)
    try:
        client.wait_for_workers(2, timeout=60)
        yield client
    finally:
        client.close()
        cluster.close()


def _square(x: int) -> int:
    return x * x


def _raise_on_three(x: int) -> int:
    if x == 3:
        raise ValueError(f"no {x}")
    return x


def test_missing_extra_is_a_one_line_error(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    monkeypatch.setitem(sys.modules, "hil.bench.executors_dask", None)  # as without the extra
    rc = cli.main(["jitter", "--sweep", "latency=0:1ms:2", "--executor", "dask", "--out",
                   str(tmp_path / "s"), "--bench", "virtual-inprocess"])  # fmt: skip
    err = capsys.readouterr().err
    assert rc == 2
    assert err == f"hil jitter: error: {MISSING_DASK}\n"
    assert MISSING_DASK == "--executor dask needs the optional extra: pip install 'ddbench[dask]'"
    assert not (tmp_path / "s").exists()  # nothing ran


def test_unknown_executor_is_refused_by_the_parser(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        cli.main(["jitter", "--sweep", "latency=0:1ms:2", "--executor", "ray"])
    assert "expected serial, process, dask or a Dask scheduler address" in capsys.readouterr().err


def test_no_scheduler_is_a_one_line_error() -> None:
    pytest.importorskip("distributed")
    from hil.bench.executors_dask import DaskExecutor

    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    executor = make_executor(f"tcp://127.0.0.1:{port}")
    assert isinstance(executor, DaskExecutor)
    executor.connect_timeout_s = 1.0
    with pytest.raises(ExecutorUnavailableError) as err:
        list(executor.run(_square, [1, 2]))
    assert f"--executor tcp://127.0.0.1:{port}: no Dask scheduler answered" in str(err.value)
    assert "\n" not in str(err.value)


def test_outcomes_and_map_on_a_cluster(dask_client: Any) -> None:
    from hil.bench.executors_dask import DaskExecutor

    executor = DaskExecutor(client=dask_client, timeout_s=BATCH_TIMEOUT_S, log=None)
    assert list(executor.map(_square, range(6))) == [0, 1, 4, 9, 16, 25]
    outcomes = sorted(executor.run(_raise_on_three, range(5)), key=lambda o: o.index)
    assert [o.result for o in outcomes if o.ok] == [0, 1, 2, 4]
    bad = outcomes[3]
    assert not bad.ok and bad.item == 3 and bad.error == "ValueError: no 3"
    assert bad.attempts == 2  # Dask ran it again (retries=1)
    with pytest.raises(TaskFailedError, match="job 4 failed: ValueError: no 3"):
        list(executor.map(_raise_on_three, range(5)))
    assert executor.describe()["workers"] == 2
    # the serial executor reports the same failure the same way (once: nothing to retry)
    serial = {o.index: o for o in SerialExecutor().run(_raise_on_three, range(5))}
    assert serial[3].error == bad.error and serial[3].attempts == 1


def test_dask_sweep_is_byte_identical_to_serial(
    dask_client: Any, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The same sweep (control and identification at 2 latency levels), serial in this
    process and from the CLI on the cluster's scheduler (`--executor tcp://...`), into the same
    --out: the same sweep.json and point.json up to wall times and the executor, and the same
    recordings, byte for byte."""
    out = tmp_path / "run" / "sweep"
    spec = "latency=0:2ms:2"
    serial = sweep(sweep_args(out, spec, "--study-duration", "1.0"), SerialExecutor(), False)
    assert serial["status"] == "complete", serial["failures"]
    (tmp_path / "run").rename(tmp_path / "serial")
    address = dask_client.scheduler.address
    rc = cli.main(["jitter", "--sweep", spec, "--executor", address, "--bench",
                   "virtual-inprocess", "--out", str(out), "--study-duration", "1.0", "--no-plot",
                   "--json"])  # fmt: skip
    captured = capsys.readouterr()
    assert rc == 0, captured.err
    on_dask = json.loads(captured.out)
    assert on_dask["executor"] == {"kind": "dask", "scheduler": address, "workers": 2}
    assert "identify" in on_dask["points"][1]["result"]  # the identification ran on a worker
    assert json.dumps(reproducible(on_dask)) == json.dumps(reproducible(serial))
    saved = json.loads((out / "sweep.json").read_text())
    assert json.dumps(reproducible(saved)) == json.dumps(reproducible(serial))
    # progress on stderr, one line per point as it finished
    assert captured.err.count("hil jitter: point ") == 2
    serial_dir = tmp_path / "serial" / "sweep"
    recordings = sorted(p.relative_to(out) for p in out.rglob("*") if p.name in
                        ("point.json", "signals.csv", "effects.toml"))  # fmt: skip
    assert len(recordings) >= 2 + 2 * 2 + 1  # point.json, control and excitation runs, effects
    for rel in recordings:
        a, b = (serial_dir / rel).read_bytes(), (out / rel).read_bytes()
        if rel.name == "point.json":
            a, b = (json.dumps(reproducible(json.loads(x))).encode() for x in (a, b))
        assert a == b, rel


def _die_once(markers: str, x: int) -> int:
    marker = Path(markers) / str(x)
    if x == 1 and not marker.exists():
        marker.touch()
        os.kill(os.getpid(), signal.SIGKILL)
    return x * x


@pytest.mark.slow  # ~15 s on a loaded machine: a cluster of its own, a worker restarted
def test_own_local_cluster_retries_a_dead_workers_job(tmp_path: Path) -> None:
    """`--executor dask`: a LocalCluster of its own (allowed-failures 0: the scheduler fails a
    dead worker's job at once), the job run again elsewhere, the cluster closed after."""
    pytest.importorskip("distributed")
    executor = make_executor("dask", workers=2)
    executor.timeout_s = BATCH_TIMEOUT_S  # type: ignore[attr-defined]
    outcomes = sorted(executor.run(partial(_die_once, str(tmp_path)), range(4)),
                      key=lambda o: o.index)  # fmt: skip
    assert [o.result for o in outcomes] == [0, 1, 4, 9]
    assert [o.attempts for o in outcomes] == [1, 2, 1, 1]
    assert executor.describe() == {"kind": "dask", "scheduler": "LocalCluster", "workers": 2}


def _sabotaged_point(markers: str, spec: PointSpec) -> dict[str, Any]:
    """run_point, except that the 1 ms point kills its worker process on its first attempt
    and the 2 ms point on every attempt (SIGKILL: no cleanup, as a crash or the OOM killer)."""
    first = Path(markers) / f"{spec.level:g}"
    if spec.level == 2e-3 or (spec.level == 1e-3 and not first.exists()):
        first.touch()
        os.kill(os.getpid(), signal.SIGKILL)
    return run_point(spec)


class Sabotaged:
    """An executor whose jobs run through :func:`_sabotaged_point`."""

    def __init__(self, inner: Any, markers: Path) -> None:
        self.inner, self.markers = inner, markers

    def run(self, fn: Callable[..., Any], items: Iterable[Any]) -> Iterator[Outcome[Any, Any]]:
        assert fn is run_point
        return self.inner.run(partial(_sabotaged_point, str(self.markers)), items)

    def describe(self) -> dict[str, Any]:
        return self.inner.describe()


def test_a_killed_worker_loses_only_its_point(
    dask_client: Any, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """3 points on 2 workers: the 1 ms point's worker dies once (it is retried and kept), the
    2 ms point's worker dies on both attempts (it is reported lost, with its parameters), the
    baseline is untouched; the sweep is written, status incomplete."""
    from hil.bench.executors_dask import DaskExecutor

    markers = tmp_path / "markers"
    markers.mkdir()
    executor = DaskExecutor(client=dask_client, timeout_s=BATCH_TIMEOUT_S)
    out = tmp_path / "sweep"
    args = sweep_args(out, "latency=0:2ms:3", "--no-identify", "--study-duration", "0.5")
    doc = sweep(args, Sabotaged(executor, markers), progress=True)
    err = capsys.readouterr().err
    assert doc["status"] == "incomplete"
    (lost,) = doc["lost_points"]
    assert lost["point"]["level"] == 2e-3 and lost["point"]["seed"] == 0
    assert lost["point"]["out_dir"] == str(out / "points" / "latency-02-seed0")
    assert lost["error"].startswith("KilledWorker") and lost["attempts"] == 2
    baseline, retried, gone = doc["points"]
    assert gone["result"] is None
    for point in (baseline, retried):
        assert point["result"]["control"]["ct"]["status"] == "complete"
    assert (markers / "0.001").exists()  # the 1 ms point did die once
    assert doc["failures"] == [f"{out / 'points' / 'latency-02-seed0'}: point lost: "
                               f"{lost['error']}"]  # fmt: skip
    ct = doc["control"]["ct"]["max_position_error_rad"]
    assert [s["n"] for s in ct] == [1, 1, 0]  # the lost level has no runs, the others theirs
    assert json.loads((out / "sweep.json").read_text())["lost_points"] == json.loads(
        json.dumps([lost])
    )
    assert err.count("retrying it") == 2  # the 1 ms point once, the 2 ms point once
    assert "(latency 2 ms, seed 0) LOST after 2 attempt(s): KilledWorker" in err
    assert err.count("hil jitter: point ") == 3
    # the cluster is whole again: both workers back for the next batch
    assert list(executor.map(_square, range(4))) == [0, 1, 4, 9]


def test_batch_timeout_reports_the_unfinished(dask_client: Any) -> None:
    from hil.bench.executors_dask import DaskExecutor

    executor = DaskExecutor(client=dask_client, timeout_s=0.5, log=None)
    outcomes = list(executor.run(_sleep, [3.0]))
    assert [o.error for o in outcomes] == ["TimeoutError: no result within the batch's 0.5 s"]


def _sleep(seconds: float) -> float:
    import time

    time.sleep(seconds)
    return seconds


@pytest.mark.slow  # ~20 s on a loaded machine: two more interpreters and 4 simulations
def test_diagnose_set_on_dask_is_the_serial_set(dask_client: Any, tmp_path: Path) -> None:
    """tests/benchmarks/make_diagnose_set.py: the first 2 recordings of the blind-like set,
    serial here and on the cluster from the command line: the same truth.json and the same
    signals, byte for byte."""
    import importlib.util
    import subprocess

    script = Path(__file__).parent / "benchmarks" / "make_diagnose_set.py"
    spec = importlib.util.spec_from_file_location("make_diagnose_set", script)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    assert module.main(["--out", str(tmp_path / "serial"), "--only", "2"]) == 0
    done = subprocess.run(
        [sys.executable, str(script), "--out", str(tmp_path / "dask"), "--only", "2",
         "--executor", dask_client.scheduler.address],
        capture_output=True, text=True, timeout=BATCH_TIMEOUT_S,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    summary = json.loads(done.stdout)
    assert summary["recordings"] == 2 and summary["executor"]["kind"] == "dask"
    assert done.stderr.count("make_diagnose_set: ") == 3  # the plan, then one line each
    for rel in ("truth.json", "rec-01/signals.csv", "rec-02/signals.csv"):
        assert (tmp_path / "serial" / rel).read_bytes() == (tmp_path / "dask" / rel).read_bytes()
