"""Moved to :mod:`insulator_rs.report` (the report writer and its deliverables); this name is
kept while the flight loop moves to :mod:`insulator_rs.flight`."""

from insulator_rs.report.writer import ReportWriter

__all__ = ["ReportWriter"]
