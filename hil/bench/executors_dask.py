"""The Dask executor: the jobs of a batch on a dask.distributed cluster (the optional extra
``pip install 'ddbench[dask]'``; hil/bench/executors.py imports this module only when asked for it).

``DaskExecutor()`` starts a ``LocalCluster`` of ``workers`` processes on this machine (loopback
only, no dashboard) for each batch and closes it after; ``DaskExecutor("tcp://HOST:8786")``
uses an existing scheduler and its workers; ``DaskExecutor(client=...)`` a client you hold.

Dispatch. A job is a whole lockstep run (or analysis) that starts its own virtual robot and
captures stderr into its own log, which is per process, so a worker process runs one job at a
time: each job is pinned (``workers=[address]``, ``allow_other_workers=False``) to a worker
that has none, and the next job is submitted when a worker is free. A worker that dies then
takes down only its own job. That job is submitted once more (``retries``, default 1) on another
(or the restarted) worker, and if that worker dies too it is reported failed with its item.
A job that *raises* is retried by Dask itself (``client.submit(..., retries=1)``). The
scheduler's ``distributed.scheduler.allowed-failures`` decides only how a worker's death shows:
0 (the LocalCluster's setting) fails the pinned job at once with ``KilledWorker``; a higher
value (Dask's default 3) leaves it waiting for a worker that is gone, which this executor notices
on the scheduler's worker list. Either way the retry is this executor's.

Imports: dask, distributed and hil.bench.executors.
"""

from __future__ import annotations

import logging
import os
import sys
import time
import uuid
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import CancelledError
from typing import Any, TypeVar

import distributed
from distributed import Client, LocalCluster
from distributed.scheduler import KilledWorker

from hil.bench.jobs import ExecutorUnavailableError, OrderedMap, Outcome, failed, one_line

T = TypeVar("T")
R = TypeVar("R")


def stderr_log(message: str) -> None:
    print(f"dask: {message}", file=sys.stderr, flush=True)


class DaskExecutor(OrderedMap):
    """Jobs on a Dask cluster, one per worker process at a time (see the module docstring).

    ``timeout_s`` bounds a whole batch: jobs without a result by then are reported failed.
    """

    def __init__(
        self,
        address: str | None = None,
        *,
        workers: int | None = None,
        client: Client | None = None,
        retries: int = 1,
        timeout_s: float | None = None,
        connect_timeout_s: float = 10.0,
        poll_s: float = 0.25,
        log: Callable[[str], None] | None = stderr_log,
    ) -> None:
        if workers is not None and workers < 1:
            raise ValueError(f"workers must be >= 1, got {workers}")
        if retries < 0:
            raise ValueError(f"retries must be >= 0, got {retries}")
        self.address = address
        self.workers = workers
        self.client = client
        self.retries = retries
        self.timeout_s = timeout_s
        self.connect_timeout_s = connect_timeout_s
        self.poll_s = poll_s
        self.log = log or (lambda message: None)
        self.workers_seen = 0  # the most workers one batch had

    # ---- the cluster --------------------------------------------------------------------
    def _connect(self) -> tuple[Client, Callable[[], None]]:
        """A client, and how to let go of what this call started."""
        if self.client is not None:
            return self.client, lambda: None
        if self.address is not None:
            try:
                client = Client(self.address, timeout=self.connect_timeout_s)
            except (OSError, TimeoutError) as exc:
                raise ExecutorUnavailableError(
                    f"--executor {self.address}: no Dask scheduler answered within "
                    f"{self.connect_timeout_s:g} s ({one_line(exc)})"
                ) from None
            return client, client.close
        cluster = LocalCluster(
            n_workers=self.workers or os.cpu_count() or 1,
            threads_per_worker=1,  # one job per process (see the module docstring)
            processes=True,
            host="127.0.0.1",  # loopback only
            dashboard_address=None,
            silence_logs=logging.ERROR,
            scheduler_kwargs={
                "allowed_failures": 0,  # a dead worker fails its job at once
                "dashboard_address": "127.0.0.1:0",  # its HTTP server: any free loopback port
            },
        )
        client = Client(cluster)

        def close() -> None:
            client.close()
            cluster.close()

        return client, close

    def _live_workers(self, client: Client) -> list[str]:
        """The scheduler's running workers, asked now. (Not ``client.scheduler_info()``: the
        client's periodic refresh may replace its answer with one without the workers.)"""
        info = client.sync(client.scheduler.identity, n_workers=-1)["workers"]
        return sorted(a for a, w in info.items() if w.get("status", "running") == "running")

    # ---- the batch ----------------------------------------------------------------------
    def run(self, fn: Callable[[T], R], items: Iterable[T]) -> Iterator[Outcome[T, R]]:
        jobs = list(items)
        if not jobs:
            return
        client, close = self._connect()
        try:
            yield from self._dispatch(client, fn, jobs)
        finally:
            close()

    def _dispatch(
        self, client: Client, fn: Callable[[T], R], jobs: list[T]
    ) -> Iterator[Outcome[T, R]]:
        batch = uuid.uuid4().hex[:8]
        name = getattr(fn, "__name__", "job")
        pending = deque(range(len(jobs)))
        attempts = [0] * len(jobs)
        running: dict[distributed.Future, tuple[int, str]] = {}
        deadline = None if self.timeout_s is None else time.monotonic() + self.timeout_s
        waiting_said = False
        absent: dict[str, int] = {}  # polls in a row a busy worker was not on the list

        def lost(i: int, worker: str, why: str) -> Outcome[T, R] | None:
            """A job whose worker died: once more, or failed after ``retries`` more."""
            if attempts[i] <= self.retries:
                self.log(f"job {i + 1} lost its worker {worker} ({why}); retrying it")
                pending.appendleft(i)
                return None
            return Outcome(
                i,
                jobs[i],
                error=f"KilledWorker: its worker died on each of {attempts[i]} attempts "
                f"(last {worker}: {why})",
                attempts=attempts[i],
            )

        def give_up(why: str) -> Iterator[Outcome[T, R]]:
            """Every job without a result, failed with ``why`` (the batch ends)."""
            for future in running:
                future.cancel()
            for i in sorted([i for i, _ in running.values()] + list(pending)):
                yield Outcome(i, jobs[i], error=why, attempts=attempts[i])

        while pending or running:
            try:
                live = self._live_workers(client)
            except (OSError, TimeoutError) as exc:  # the scheduler is gone: keep what came back
                yield from give_up(f"scheduler unreachable: {one_line(exc)}")
                return
            self.workers_seen = max(self.workers_seen, len(live))
            for future, (i, worker) in list(running.items()):
                if worker in live or future.done():
                    absent.pop(worker, None)
                    continue
                absent[worker] = absent.get(worker, 0) + 1
                if absent[worker] >= 2:  # gone (twice in a row): the job waits in vain
                    del running[future], absent[worker]
                    future.cancel()
                    if (out := lost(i, worker, "it left the cluster")) is not None:
                        yield out
            busy = {worker for _, worker in running.values()}
            for worker in live:
                if not pending:
                    break
                if worker in busy:
                    continue
                i = pending.popleft()
                attempts[i] += 1
                future = client.submit(
                    fn,
                    jobs[i],
                    key=f"{name}-{batch}-{i}-{attempts[i]}",
                    workers=[worker],
                    allow_other_workers=False,
                    retries=self.retries,  # a job that raises: Dask runs it again
                )
                running[future] = (i, worker)
            if deadline is not None and time.monotonic() > deadline:
                yield from give_up(
                    f"TimeoutError: no result within the batch's {self.timeout_s:g} s"
                )
                return
            if not running:
                if not waiting_said:
                    self.log("waiting for a worker")
                    waiting_said = True
                time.sleep(self.poll_s)
                continue
            waiting_said = False
            try:
                done, _ = distributed.wait(
                    list(running), timeout=self.poll_s, return_when="FIRST_COMPLETED"
                )
            except TimeoutError:
                continue
            except CancelledError as exc:  # the client lost its scheduler
                yield from give_up(f"scheduler unreachable: {one_line(exc)}")
                return
            for future in sorted(done, key=lambda f: running[f][0]):
                i, worker = running.pop(future)
                status = future.status
                result = future.result() if status == "finished" else None
                exc = future.exception() if status == "error" else None
                # the result is here now: let the worker forget it, or a later death of that
                # worker would make the scheduler compute the job again
                future.release()
                if status == "finished":
                    yield Outcome(i, jobs[i], result, attempts=attempts[i])
                    continue
                if exc is None or isinstance(exc, KilledWorker):
                    if (out := lost(i, worker, "it died" if exc else status)) is not None:
                        yield out
                else:  # the job raised on each of its 1 + retries runs
                    yield failed(i, jobs[i], exc, attempts=attempts[i] + self.retries)

    def describe(self) -> dict[str, Any]:
        if self.client is not None:
            scheduler = self.client.scheduler.address
        else:
            scheduler = self.address or "LocalCluster"
        workers = self.workers_seen or self.workers or (None if self.address else os.cpu_count())
        return {"kind": "dask", "scheduler": scheduler, "workers": workers}
