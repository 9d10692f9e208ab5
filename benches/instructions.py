"""Instruction-count guard for the fusion_core kernels (issue 23): counts, not timings.

    python benches/instructions.py            # compare with benches/instructions.json; exit 1 on a regression
    python benches/instructions.py --update   # measure and rewrite the table (commit it)

Timings on these shared machines move by tens of percent with whatever else runs; valgrind's
callgrind counts the instructions a run executes, the same whatever the load. Each kernel of
``crates/fusion_core/examples/instructions.rs`` runs once on fixed inputs under callgrind, and
once building the inputs only (``--setup-only``); the difference is the kernel's count. Rayon
runs one thread (RAYON_NUM_THREADS=1): how work splits across threads would move the counts.
A kernel more than :data:`TOLERANCE` above its committed count fails; one far below is
reported (commit the new table). Counts belong to a compiler: the table records rustc's
version, and another version's counts are printed and not judged (a new compiler re-bases the
table with ``--update``). Without valgrind it says so and exits 0 (CI installs it from Debian).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TABLE = ROOT / "benches" / "instructions.json"
EXAMPLE = "instructions"
KERNELS = ("project_points_20k", "points_in_boxes_20k", "deskew_20k", "deskew_points_in_boxes_20k",
           "dbscan_3k", "dbscan_30k", "dbscan_sparse_10k", "pca_2k", "localize_dbscan_ransac_2k")
#: The most a kernel may grow over its committed count (the issue's +5 %).
TOLERANCE = 0.05
COLLECTED = re.compile(r"Collected\s*:\s*(\d+)")


def rustc_version() -> str:
    return subprocess.run(["rustc", "--version"], capture_output=True, text=True, check=True).stdout.strip()


def build() -> Path:
    """The example, built in release (the profile the wheel ships)."""
    subprocess.run(["cargo", "build", "--release", "--quiet", "-p", "fusion_core", "--example", EXAMPLE],
                   cwd=ROOT, check=True)
    target = Path(os.environ.get("CARGO_TARGET_DIR", ROOT / "target"))
    return target / "release" / "examples" / EXAMPLE


def collected(binary: Path, kernel: str, setup_only: bool) -> int:
    args = ["valgrind", "--tool=callgrind", "--callgrind-out-file=/dev/null", str(binary), kernel]
    if setup_only:
        args.append("--setup-only")
    run = subprocess.run(args, capture_output=True, text=True, env={**os.environ, "RAYON_NUM_THREADS": "1"})
    match = COLLECTED.search(run.stderr)
    if run.returncode != 0 or match is None:
        raise RuntimeError(f"{kernel}: callgrind run failed (exit {run.returncode}): {run.stderr[-500:]}")
    return int(match.group(1))


def measure(binary: Path) -> dict[str, int]:
    counts = {}
    for kernel in KERNELS:
        counts[kernel] = collected(binary, kernel, False) - collected(binary, kernel, True)
        print(f"  {kernel:30s} {counts[kernel]:>14,d} instructions", flush=True)
    return counts


def compare(counts: dict[str, int], table: dict) -> list[str]:
    """The regressions (count above the table's by more than TOLERANCE), one line each."""
    failures = []
    print(f"{'kernel':30s} {'committed':>14s} {'now':>14s} {'ratio':>7s}")
    for kernel, now in counts.items():
        then = table["counts"].get(kernel)
        if then is None:
            print(f"{kernel:30s} {'(new)':>14s} {now:>14,d}")
            continue
        ratio = now / then
        flag = "  REGRESSION" if ratio > 1 + TOLERANCE else ("  faster: --update the table" if ratio < 1 - TOLERANCE else "")
        print(f"{kernel:30s} {then:>14,d} {now:>14,d} {ratio:7.3f}{flag}")
        if ratio > 1 + TOLERANCE:
            failures.append(f"{kernel}: {now:,d} instructions, {100 * (ratio - 1):+.1f} % over the committed {then:,d}")
    return failures


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--update", action="store_true", help="rewrite benches/instructions.json with this run")
    args = parser.parse_args(argv)
    if shutil.which("valgrind") is None:
        print("instructions: valgrind is not installed; the instruction-count guard did not run")
        return 0
    version = rustc_version()
    binary = build()
    print(f"instruction counts ({version}, callgrind, one thread):")
    counts = measure(binary)
    if args.update or not TABLE.exists():
        TABLE.write_text(json.dumps({"rustc": version, "tolerance": TOLERANCE, "counts": counts}, indent=2) + "\n")
        print(f"instructions: wrote {TABLE.relative_to(ROOT)}")
        return 0
    table = json.loads(TABLE.read_text())
    if table.get("rustc") != version:
        print(f"instructions: the table was measured with {table.get('rustc')!r}, this is {version!r}: "
              f"counts printed, not judged (re-base with --update)")
        compare(counts, table)
        return 0
    failures = compare(counts, table)
    for line in failures:
        print(f"FAIL {line}", file=sys.stderr)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
