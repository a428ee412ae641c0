"""Logging set-up of the command lines (`hil`, `virtual-robot`): levels, one format, rate limit.

Without a handler, Python prints every WARNING of every library on stderr (logging's "last
resort"): with a socketcand port dead, python-can's connect loop logged "Failed to connect to
server" about 700,000 times in its 10 s before ``hil`` printed its one-line error. Here:

* one stderr handler, lines ``PROG: LOGGER: LEVEL: message``, one line each (a message's
  further lines and a traceback in it, like an exception's, only with the root logger at
  DEBUG);
* the project's loggers (``hil``, ``drivers``, ``virtual_robot``, ``profiles``) at WARNING, the
  third-party ones (``can``, ``canopen``, everything else) at ERROR, those whose errors are
  raised to the command as well (:data:`RAISED`) at CRITICAL; ``-v`` lowers each by one step
  (INFO / WARNING / ERROR), ``-vv`` by two, ``-q`` raises them one step;
* a rate limit on the handler: a message repeated from one logger passes :data:`BURST` times
  (the last of them saying so), then at most once per :data:`WINDOW_S`, that line saying how
  many were suppressed.

Lives in ``drivers`` because both command lines (host and virtual robot) use it; imports the
standard library only.
"""

from __future__ import annotations

import logging
import sys
import time

OWN = ("hil", "drivers", "virtual_robot", "profiles")
THIRD_PARTY = ("can", "canopen")
# third-party loggers whose errors always come back as the exception the command then reports
# in its own one line (canopen's SDO client logs "Transfer aborted by client", then raises): a
# step quieter, shown from -v on (an SDO read that timed out printed two error lines)
RAISED = ("canopen.sdo.client",)
BURST = 3  # identical messages that pass before the limit applies
WINDOW_S = 10.0  # then at most one per this many seconds

_LEVELS = [logging.DEBUG, logging.INFO, logging.WARNING, logging.ERROR, logging.CRITICAL]
_TRACEBACK = "Traceback (most recent call last)"


class RateLimit(logging.Filter):
    """Pass a message (logger, level, text) :data:`BURST` times, then once per ``window_s``,
    telling how many were dropped in between."""

    def __init__(self, burst: int = BURST, window_s: float = WINDOW_S) -> None:
        super().__init__()
        self.burst, self.window_s = burst, window_s
        self._seen: dict[tuple[str, int, str], list[float]] = {}  # key -> [count, last, dropped]

    def filter(self, record: logging.LogRecord) -> bool:
        key = (record.name, record.levelno, str(record.msg)[:80])
        now = time.monotonic()
        state = self._seen.get(key)
        if state is None:
            if len(self._seen) > 1000:  # bounded memory: forget the oldest keys
                self._seen.clear()
            self._seen[key] = [1, now, 0]
            return True
        state[0] += 1
        if state[0] <= self.burst:
            state[1] = now
            if state[0] == self.burst:  # say so now: the loop may end before the window does
                record.msg = f"{record.msg} (repeats shown once per {self.window_s:g} s from here)"
            return True
        if now - state[1] < self.window_s:
            state[2] += 1
            return False
        if state[2]:
            record.msg = f"{record.msg} ({int(state[2])} similar messages suppressed)"
        state[1], state[2] = now, 0
        return True


class _Format(logging.Formatter):
    def __init__(self, prog: str) -> None:
        super().__init__()
        self.prog = prog

    def format(self, record: logging.LogRecord) -> str:
        message = record.getMessage()
        debug = logging.getLogger().isEnabledFor(logging.DEBUG)
        if not debug:
            # one line: python-can formats a traceback into some messages (socketcand's
            # "Failed to receive: [Errno 104] Connection reset by peer  Traceback ..."); the
            # whole text, like an exception's, only when debugging
            first = message.split("\n", 1)[0].split(_TRACEBACK, 1)[0].rstrip()
            message = first or message.strip().split("\n", 1)[0]
        text = f"{self.prog}: {record.name}: {record.levelname.lower()}: {message}"
        if record.exc_info and debug:
            text += "\n" + self.formatException(record.exc_info)
        return text


def configure(prog: str, verbosity: int = 0) -> logging.Handler:
    """Set up logging for a command line; ``verbosity``: -1 quiet, 0 default, 1 -v, 2 -vv.
    Idempotent: a second call replaces the handler of the first."""
    root = logging.getLogger()
    for old in [h for h in root.handlers if getattr(h, "ddbench", False)]:
        root.removeHandler(old)
    handler = logging.StreamHandler(sys.stderr)
    handler.ddbench = True  # type: ignore[attr-defined]
    handler.setFormatter(_Format(prog))
    handler.addFilter(RateLimit())
    root.addHandler(handler)

    def level(default: int) -> int:
        i = _LEVELS.index(default) - max(-1, min(verbosity, 2))
        return _LEVELS[max(0, min(i, len(_LEVELS) - 1))]

    root.setLevel(level(logging.ERROR))
    for name in THIRD_PARTY:
        logging.getLogger(name).setLevel(level(logging.ERROR))
    for name in RAISED:
        logging.getLogger(name).setLevel(level(logging.CRITICAL))
    for name in OWN:
        logging.getLogger(name).setLevel(level(logging.WARNING))
    logging.captureWarnings(True)
    return handler


def add_verbosity_options(parser: object, *, subcommand: bool = False) -> None:
    """``-v``/``--verbose`` (repeatable) and ``-q``/``--quiet`` on an argparse parser. On a
    subcommand's parser (``subcommand=True``) they have no default, so the values given before
    the subcommand stand unless the option is given again after it."""
    import argparse

    parser.add_argument(  # type: ignore[attr-defined]
        "-v",
        "--verbose",
        action="count",
        default=argparse.SUPPRESS if subcommand else 0,
        help="more log output (-v: warnings of python-can/canopen, -vv: debug)",
    )
    parser.add_argument(  # type: ignore[attr-defined]
        "-q",
        "--quiet",
        action="store_true",
        default=argparse.SUPPRESS if subcommand else False,
        help="errors only",
    )


def verbosity(args: object) -> int:
    """-1 for --quiet, else the number of -v."""
    return -1 if getattr(args, "quiet", False) else int(getattr(args, "verbose", 0) or 0)
