"""Report stage: figures (PNG), the self-contained HTML report, ``metrics.json`` and
``run_info.json``.

Figures live in :mod:`calnet.report.figures` (matplotlib imported lazily); this package
exports only the HTML and metrics writers.
"""

from calnet.report.html import Headline, Section, Table, fmt, render_report, write_report
from calnet.report.metrics import to_jsonable, write_metrics, write_run_info

__all__ = ["Headline", "Section", "Table", "fmt", "render_report", "write_report", "to_jsonable",
           "write_metrics", "write_run_info"]
