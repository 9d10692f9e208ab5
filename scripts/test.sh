#!/usr/bin/env bash
# The project's test command (README): Rust crates with cargo, the stub check, mypy, then
# the Python suite against the installed package. Run from the repository root inside the venv.
set -euo pipefail
cd "$(dirname "$0")/.."
echo "== cargo test (fusion_core, scene_raycast, livox_mid360)"
cargo test --release -p fusion_core -p scene_raycast -p livox_mid360
echo "== stub check (_core.pyi against the compiled module)"
python -m mypy.stubtest insulator_rs._core --allowlist scripts/stubtest_allowlist.txt
if [ "${INSULATOR_RS_MYPY:-1}" = "1" ]; then
  echo "== mypy (python/insulator_rs; settings: pyproject.toml [tool.mypy])"
  python -m mypy
else
  # numpy's stubs differ between the numpy pip picks for 3.10 and for 3.11 (the same code types
  # differently): CI gates mypy once, in its 3.11 venv
  echo "== mypy: not in this venv (INSULATOR_RS_MYPY=0)"
fi
echo "== pytest (hypothesis profile: ${HYPOTHESIS_PROFILE:-ci})"
# The gate draws the same examples on every run (tests/conftest.py, profile "ci");
# HYPOTHESIS_PROFILE=dev explores new ones.
HYPOTHESIS_PROFILE="${HYPOTHESIS_PROFILE:-ci}" python -m pytest -q "$@"
