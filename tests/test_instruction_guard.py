"""The instruction-count guard's judgement (benches/instructions.py): above the committed count by
more than its tolerance fails, within it passes, and the committed table covers every kernel the
guard runs. The counts themselves are measured by CI under valgrind (.ci/run)."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _guard():
    spec = importlib.util.spec_from_file_location("instructions_guard", ROOT / "benches" / "instructions.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def test_more_than_five_percent_over_the_table_fails_and_less_passes(capsys):
    guard = _guard()
    table = {"counts": {"dbscan_3k": 1_000_000, "pca_2k": 100_000}}
    assert guard.compare({"dbscan_3k": 1_049_000, "pca_2k": 90_000}, table) == []
    failures = guard.compare({"dbscan_3k": 1_051_000, "pca_2k": 100_000}, table)
    assert len(failures) == 1 and failures[0].startswith("dbscan_3k: 1,051,000 instructions, +5.1 %")
    assert "faster: --update" in capsys.readouterr().out  # pca_2k at 0.90 is reported


def test_the_committed_table_covers_every_kernel():
    guard = _guard()
    table = json.loads(guard.TABLE.read_text())
    assert set(table["counts"]) == set(guard.KERNELS)
    assert table["tolerance"] == guard.TOLERANCE and table["rustc"].startswith("rustc ")
    assert all(isinstance(v, int) and v > 0 for v in table["counts"].values())
