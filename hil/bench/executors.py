"""Executors: run independent jobs (the points of a sweep, the recordings of a set) one after
another, on a local process pool, or on a Dask cluster.

``fn`` is a module-level function and the items and results are picklable, so the same batch
runs on any engine. Every executor has

* ``run(fn, items)``: yields one :class:`Outcome` per item *as each job finishes* (for progress
  on stderr), a failed job included (its ``error``, the item it was given, the attempts made);
* ``map(fn, items)``: the results in the order of the items (raises :class:`TaskFailedError` on the
  first failed job), for callers that need all or nothing;
* ``describe()``: what ran the jobs, for the batch's JSON.

Engines:

* :class:`SerialExecutor` (``--executor serial``): in this process, one after another.
* :class:`LocalProcessExecutor` (``--executor process``, default): a pool of ``--workers``
  spawned processes on this machine. A worker process that dies breaks the pool: the jobs not
  yet finished are reported failed.
* :class:`hil.bench.executors_dask.DaskExecutor` (``--executor dask``: a ``LocalCluster`` of
  ``--workers`` processes here; ``--executor tcp://HOST:8786``: an existing scheduler): needs
  the optional extra ``pip install 'ddbench[dask]'``. One job per worker process at a time; a
  worker that dies loses only its job, which runs once more on another worker and is then
  reported failed (docs/scaling.md).

Each job of a sweep starts its own virtual robot (a subprocess, or a thread for the in-process
bench) and writes only under its own directory, so jobs share nothing but the file system.
This module imports only the standard library, :mod:`hil.bench.jobs` (what every executor
shares) and hil.bench.executors_dask on demand.
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from typing import Any, TypeVar

from hil.bench.jobs import (
    Executor,
    ExecutorUnavailableError,
    OrderedMap,
    Outcome,
    failed,
)

T = TypeVar("T")
R = TypeVar("R")

KINDS = ("serial", "process", "dask")
MISSING_DASK = "--executor dask needs the optional extra: pip install 'ddbench[dask]'"


class SerialExecutor(OrderedMap):
    """One job after another, in this process."""

    def run(self, fn: Callable[[T], R], items: Iterable[T]) -> Iterator[Outcome[T, R]]:
        for i, item in enumerate(items):
            try:
                result = fn(item)
            except Exception as exc:  # a job's failure is reported, the batch goes on
                yield failed(i, item, exc)
                continue
            yield Outcome(i, item, result)

    def describe(self) -> dict[str, Any]:
        return {"kind": "serial", "workers": 1}


class LocalProcessExecutor(OrderedMap):
    """A pool of ``max_workers`` processes (default: one per CPU). Workers are started with
    ``spawn`` (a clean interpreter: no inherited threads or open links) and reused for
    several jobs."""

    def __init__(self, max_workers: int | None = None) -> None:
        workers = (os.cpu_count() or 1) if max_workers is None else max_workers
        if workers < 1:
            raise ValueError(f"max_workers must be >= 1, got {workers}")
        self.max_workers = workers

    def run(self, fn: Callable[[T], R], items: Iterable[T]) -> Iterator[Outcome[T, R]]:
        jobs = list(items)
        if not jobs:
            return
        context = multiprocessing.get_context("spawn")
        workers = min(self.max_workers, len(jobs))
        with ProcessPoolExecutor(max_workers=workers, mp_context=context) as pool:
            futures = {pool.submit(fn, job): i for i, job in enumerate(jobs)}
            pending = set(futures)
            while pending:
                finished, pending = wait(pending, return_when=FIRST_COMPLETED)
                for future in sorted(finished, key=futures.__getitem__):
                    i = futures[future]
                    try:
                        yield Outcome(i, jobs[i], future.result())
                    except BrokenProcessPool as exc:  # a worker died: the pool is lost
                        why = "a worker died and took the pool's unfinished jobs with it"
                        out = failed(i, jobs[i], exc)
                        yield Outcome(i, jobs[i], error=f"{out.error} ({why})", detail=out.detail)
                    except Exception as exc:
                        yield failed(i, jobs[i], exc)

    def describe(self) -> dict[str, Any]:
        return {"kind": "process", "workers": self.max_workers}


def make_executor(kind: str, workers: int | None = None) -> Executor:
    """``"serial"``, ``"process"`` (``workers`` processes, default one per CPU), ``"dask"``
    (a LocalCluster of ``workers`` processes) or a Dask scheduler address ``tcp://HOST:PORT``.
    Raises :class:`ExecutorUnavailableError` when Dask is asked for and not installed."""
    if kind == "serial":
        return SerialExecutor()
    if kind == "process":
        return LocalProcessExecutor(workers)
    if kind == "dask" or is_scheduler_address(kind):
        try:
            from hil.bench.executors_dask import DaskExecutor
        except ImportError:  # dask.distributed is the optional extra
            raise ExecutorUnavailableError(MISSING_DASK) from None
        return DaskExecutor(None if kind == "dask" else kind, workers=workers)
    raise ValueError(
        f"unknown executor {kind!r}; expected serial, process, dask or a Dask scheduler "
        "address tcp://HOST:PORT"
    )


def is_scheduler_address(text: str) -> bool:
    """A Dask scheduler address: ``tcp://HOST:PORT`` (or tls://, ws://, wss://)."""
    scheme, sep, rest = text.partition("://")
    return bool(sep) and scheme in ("tcp", "tls", "ws", "wss") and bool(rest)


def executor_kind(text: str) -> str:
    """argparse type of ``--executor``: a kind of :data:`KINDS` or a scheduler address."""
    if text in KINDS or is_scheduler_address(text):
        return text
    raise argparse.ArgumentTypeError(
        f"{text!r}: expected serial, process, dask or a Dask scheduler address tcp://HOST:PORT"
    )


def add_executor_arguments(p: Any, default: str = "process") -> None:
    """``--executor`` and ``--workers`` on ``p`` (a parser or an argument group), the same for
    every command that fans out work."""
    p.add_argument(
        "--executor",
        type=executor_kind,
        default=default,
        metavar="{serial,process,dask,tcp://HOST:PORT}",
        help=f"where the jobs run (default {default}): serial, one after another; process, a "
        "pool of local processes; dask, a Dask LocalCluster on this machine; tcp://HOST:PORT, "
        "an existing Dask scheduler (docs/scaling.md)",
    )
    p.add_argument(
        "--workers",
        type=int,
        default=None,
        help="worker processes of process and dask (default: one per CPU); a scheduler's "
        "workers are its own",
    )


def executor_from_args(args: argparse.Namespace, default: str = "process") -> Executor:
    """The executor of ``--executor``/``--workers``."""
    return make_executor(getattr(args, "executor", default), getattr(args, "workers", None))


__all__ = [
    "KINDS",
    "LocalProcessExecutor",
    "SerialExecutor",
    "make_executor",
]
