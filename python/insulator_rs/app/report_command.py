"""``insulator-rs report DIR``: (re)write ``report.html`` of a report folder, a flight's or a replay's.

The page is written from the folder's own files (summary.json, inspection.geojson, images/);
see :mod:`insulator_rs.report.html`. A folder that is not a readable report is refused naming
the file (exit status 2); photos that are missing or unreadable are listed (exit status 0,
the page shows them as missing).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = subparsers.add_parser("report", help="write report.html of a report folder (flight or replay)",
                              description="""\
Write report.html of a report folder (a flight's or a replay's) from the folder's own files
(summary.json, inspection.geojson, images/). A folder that is not a readable report is refused
naming the file (exit status 2); missing or unreadable photos are listed and shown as missing.""")
    p.add_argument("folder", type=Path, help="the report folder (holds summary.json and inspection.geojson)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from insulator_rs.exceptions import ReportError
    from insulator_rs.report.html import write_report_html

    try:
        report = write_report_html(args.folder)
    except ReportError as exc:
        print(f"insulator-rs report: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:  # the folder is not writable
        print(f"insulator-rs report: error: {args.folder}: cannot write report.html: {exc.strerror}", file=sys.stderr)
        return 2
    for problem in report.problems:
        print(f"insulator-rs report: warning: {problem}", file=sys.stderr)
    print(f"{report.path}: {report.insulators} insulators, {report.photos} photos")
    return 0
