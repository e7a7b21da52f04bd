"""Monitoring reports as a plain library: a site map figure, then PDF and HTML documents.

`worker.reports.render.build_report(data, out_dir)` takes a `ReportData` (plain values and
file paths, no database) and writes `report.pdf`, `report.html` and `map.png`. The caller
gathers the data and stores the files. The renderer (reportlab, matplotlib) is not imported
here: the processes that only word alerts or gather report data do not load it.
"""

from worker.reports.data import Change, DetectionRow, ReportData

__all__ = ["Change", "DetectionRow", "ReportData"]
