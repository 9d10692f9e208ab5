#!/usr/bin/env bash
# The project's test command (README): Rust crates with cargo, then the Python suite
# against the installed package. Run from the repository root inside the venv.
set -euo pipefail
cd "$(dirname "$0")/.."
echo "== cargo test (fusion_core, scene_raycast, livox_mid360)"
cargo test --release -p fusion_core -p scene_raycast -p livox_mid360
echo "== stub check (_core.pyi against the compiled module)"
python -m mypy.stubtest insulator_rs._core --allowlist scripts/stubtest_allowlist.txt
echo "== pytest"
python -m pytest -q "$@"
