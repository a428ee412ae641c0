"""What every executor shares: a job's :class:`Outcome`, the errors, and :class:`OrderedMap`
(``map`` in item order from ``run`` as jobs finish).

Its own module so that :mod:`hil.bench.executors` (which starts the Dask executor on demand)
and :mod:`hil.bench.executors_dask` both build on it without importing each other. Standard
library only.
"""

from __future__ import annotations

import traceback
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from typing import Any, Generic, Protocol, TypeVar

T = TypeVar("T")
R = TypeVar("R")


class ExecutorUnavailableError(RuntimeError):
    """The executor asked for cannot run here (the extra is missing, no scheduler answered)."""


class TaskFailedError(RuntimeError):
    """A job of ``map`` failed (``outcome`` says which, with what, after how many attempts)."""

    def __init__(self, outcome: Outcome[Any, Any]) -> None:
        super().__init__(f"job {outcome.index + 1} failed: {outcome.error}")
        self.outcome = outcome


@dataclass(frozen=True)
class Outcome(Generic[T, R]):
    """How one job ended: ``result``, or ``error`` (one line) when it failed."""

    index: int  # position of the item in the items given to run()
    item: T
    result: R | None = None
    error: str | None = None
    detail: str | None = None  # the traceback (or the worker's fate) behind ``error``
    attempts: int = 1

    @property
    def ok(self) -> bool:
        return self.error is None


def one_line(exc: BaseException) -> str:
    """``Type: message`` on one line."""
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def failed(index: int, item: Any, exc: BaseException, attempts: int = 1) -> Outcome[Any, Any]:
    """The outcome of a job that raised ``exc``."""
    detail = "".join(traceback.format_exception(exc))
    return Outcome(index, item, error=one_line(exc), detail=detail, attempts=attempts)


class Executor(Protocol):
    """Runs ``fn`` on every item (see the module docstring)."""

    def run(self, fn: Callable[[T], R], items: Iterable[T]) -> Iterator[Outcome[T, R]]: ...

    def map(self, fn: Callable[[T], R], items: Iterable[T]) -> Iterator[R]: ...

    def describe(self) -> dict[str, Any]: ...


class OrderedMap:
    """``map`` from ``run``: the results in the order of the items, each as soon as it and
    every one before it have finished."""

    def run(self, fn: Callable[[T], R], items: Iterable[T]) -> Iterator[Outcome[T, R]]:
        raise NotImplementedError

    def map(self, fn: Callable[[T], R], items: Iterable[T]) -> Iterator[R]:
        done: dict[int, Outcome[T, R]] = {}
        following = 0
        for outcome in self.run(fn, items):
            if not outcome.ok:
                raise TaskFailedError(outcome)
            done[outcome.index] = outcome
            while following in done:
                yield done.pop(following).result  # type: ignore[misc]
                following += 1
