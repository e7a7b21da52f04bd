"""Monitoring reports as a plain library: a site map figure, then PDF and HTML documents.

`build_report(data, out_dir)` takes a `ReportData` (plain values and file paths, no
database) and writes `report.pdf`, `report.html` and `map.png`. The caller gathers the
data and stores the files.
"""

from worker.reports.data import Change, DetectionRow, ReportData
from worker.reports.render import ReportFiles, build_report

__all__ = ["Change", "DetectionRow", "ReportData", "ReportFiles", "build_report"]
