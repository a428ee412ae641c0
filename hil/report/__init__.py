"""HTML reports: ``--report FILE`` of ``hil identify``, ``hil diagnose`` and ``hil control
--compare`` (docs/reports.md).

:func:`write_report` turns a command's JSON document (the one ``--json`` prints) and the
recordings it read into one self-contained HTML file: tables, the results in words, interactive
plots (:mod:`hil.report.page`). The report depends on the results, never the reverse: the
commands import this package only inside the function that handles ``--report``.

Imports: :mod:`drivers` (reading the recordings a document names) and the standard library.
"""

from __future__ import annotations

from hil import lazy_exports

__getattr__, __dir__, __all__ = lazy_exports(
    __name__,
    {
        "hil.report.documents": ["write_report", "build_report"],
        "hil.report.page": ["Page"],
    },
)
