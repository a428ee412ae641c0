"""Executors: run independent jobs (the points of a sweep) one after another or in parallel.

An executor is anything with ``map(fn, items)`` returning the results in the order of
``items``. ``fn`` is a module-level function and the items and results are picklable, so the
same sweep runs on any engine:

* :class:`SerialExecutor`: in this process, one after another (tests, debugging).
* :class:`LocalProcessExecutor`: a pool of worker processes on this machine
  (``concurrent.futures.ProcessPoolExecutor``, ``max_workers`` default ``os.cpu_count()``).
* A cluster engine plugs in with a few lines, e.g. Dask::

      class DaskExecutor:
          def __init__(self, client):          # dask.distributed.Client
              self.client = client
          def map(self, fn, items):
              return self.client.gather(self.client.map(fn, list(items), pure=False))

  or Ray: ``remote = ray.remote(fn); return ray.get([remote.remote(x) for x in items])``.

Each job of a sweep starts its own virtual robot (a subprocess, or a thread for the in-process
bench) and writes only under its own directory, so jobs share nothing but the file system.
"""

from __future__ import annotations

import multiprocessing
import os
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ProcessPoolExecutor
from typing import Any, Protocol, TypeVar

T = TypeVar("T")
R = TypeVar("R")


class Executor(Protocol):
    """Runs ``fn`` on every item; yields the results in the order of the items."""

    def map(self, fn: Callable[[T], R], items: Iterable[T]) -> Iterable[R]: ...

    def describe(self) -> dict[str, Any]: ...


class SerialExecutor:
    """One job after another, in this process."""

    def map(self, fn: Callable[[T], R], items: Iterable[T]) -> Iterator[R]:
        for item in items:
            yield fn(item)

    def describe(self) -> dict[str, Any]:
        return {"kind": "serial", "workers": 1}


class LocalProcessExecutor:
    """A pool of ``max_workers`` processes (default: one per CPU). Workers are started with
    ``spawn`` (a clean interpreter: no inherited threads or open links) and reused for
    several jobs."""

    def __init__(self, max_workers: int | None = None) -> None:
        workers = (os.cpu_count() or 1) if max_workers is None else max_workers
        if workers < 1:
            raise ValueError(f"max_workers must be >= 1, got {workers}")
        self.max_workers = workers

    def map(self, fn: Callable[[T], R], items: Iterable[T]) -> Iterator[R]:
        jobs = list(items)
        if not jobs:
            return
        context = multiprocessing.get_context("spawn")
        workers = min(self.max_workers, len(jobs))
        with ProcessPoolExecutor(max_workers=workers, mp_context=context) as pool:
            yield from pool.map(fn, jobs)

    def describe(self) -> dict[str, Any]:
        return {"kind": "process", "workers": self.max_workers}


def make_executor(kind: str, workers: int | None = None) -> Executor:
    """``"serial"`` or ``"process"`` (``workers`` processes, default one per CPU)."""
    if kind == "serial":
        return SerialExecutor()
    if kind == "process":
        return LocalProcessExecutor(workers)
    raise ValueError(f"unknown executor {kind!r}; expected serial or process")
