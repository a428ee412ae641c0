"""Host side of the bench: loop runner, experiments, identification, control, reports (`hil`).

Packages by capability, each importing only the ones below it (tests/test_layout.py checks):

* :mod:`hil.model`: the arm's models (closed form, URDF), regressors, estimators, the
  open-loop simulator, metrics, parameter files. No I/O.
* :mod:`hil.bench`: the loop runner, ``run_experiment`` over a bench, the virtual robot's
  process, executors for batches of runs.
* :mod:`hil.identify`, :mod:`hil.diagnose`, :mod:`hil.control`: identification of θ, mismatch
  diagnosis and tracking control, each on :mod:`hil.model` (and :mod:`hil.bench` to run).
* :mod:`hil.timing`: jitter studies, timing-fault sweeps, replay, bus load.
* :mod:`hil.cli` wires the ``hil`` subcommands; :mod:`hil.cli_options` holds their shared
  options; :mod:`hil.entry` is the console entry.

Each package's public names are in its ``__all__`` and importable from the package itself
(``from hil.identify import identify``; docs/api.md). They load on first use
(:func:`lazy_exports`), so importing a package costs no more than importing the module you
need, and ``hil --help`` does not load Pinocchio or matplotlib.

Imports: the standard library only (every subpackage imports this module).
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable, Mapping, Sequence
from typing import Any

__version__ = "0.1.0"

__all__ = ["__version__", "lazy_exports"]


def lazy_exports(
    package: str, exports: Mapping[str, Sequence[str]]
) -> tuple[Callable[[str], Any], Callable[[], list[str]], list[str]]:
    """Module ``__getattr__``, ``__dir__`` and ``__all__`` for a package that re-exports names
    of its modules (PEP 562). ``exports`` maps a module to the names the package gives from
    it; the module is imported when one of its names is first looked up, then the name is
    cached on the package. Use::

        __getattr__, __dir__, __all__ = lazy_exports(__name__, {"hil.model.metrics": ["nrmse"]})
    """
    where = {name: module for module, names in exports.items() for name in names}

    def getattr_(name: str) -> Any:
        module = where.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(module), name)
        setattr(sys.modules[package], name, value)
        return value

    def dir_() -> list[str]:
        return sorted(set(vars(sys.modules[package])) | set(where))

    return getattr_, dir_, list(where)
