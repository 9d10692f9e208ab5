#!/usr/bin/env bash
# The project's test command (README). Run from the repository root inside the venv.
#
#   bash scripts/test.sh          the quick tier, before every commit (at most 5 minutes on a
#                                 2-core machine): the Rust crates' tests, the stub check, mypy, and
#                                 the pytest tests not marked slow (unit, parity, property) plus the
#                                 one small-scene flight marked smoke
#   bash scripts/test.sh --all    everything: the same, and every test marked slow
#                                 (whole-mission flights, PX4 SITL flights, training, studies)
#   bash scripts/test.sh --slow   what --all adds to the quick tier, alone (pytest only): CI runs the
#                                 quick tier, timed, then this, which together are --all
#
# Further arguments go to pytest (e.g. a file, -k, --durations=20). The markers are declared in
# pyproject.toml [tool.pytest.ini_options] and described in docs/guide/testing.md.
set -euo pipefail
cd "$(dirname "$0")/.."
t0=$SECONDS
# Each step's start, in seconds since the command began: where a tier's minutes go.
step() { echo "== [$((SECONDS - t0)) s] $*"; }

tier="quick"
case "${1:-}" in
  --all) tier="all"; shift ;;
  --slow) tier="slow"; shift ;;
esac
case "$tier" in
  quick) marker="smoke or not slow" ;;
  slow) marker="slow and not smoke" ;;
  *) marker="" ;;
esac

# The Rust crates, the stubs and mypy: in the quick tier and --all (--slow is what they leave out).
static_checks() {
  step "cargo test (fusion_core, scene_raycast, livox_mid360)"
  cargo test --quiet --release -p fusion_core -p scene_raycast -p livox_mid360
  step "stub check (_core.pyi against the compiled module)"
  python -m mypy.stubtest insulator_rs._core --allowlist scripts/stubtest_allowlist.txt
  if [ "${INSULATOR_RS_MYPY:-1}" = "1" ]; then
    step "mypy (python/insulator_rs; settings: pyproject.toml [tool.mypy])"
    python -m mypy
  else
    # numpy's stubs differ between the numpy pip picks for 3.10 and for 3.11 (the same code types
    # differently): CI gates mypy once, in its 3.11 venv
    echo "== mypy: not in this venv (INSULATOR_RS_MYPY=0)"
  fi
}
if [ "$tier" != "slow" ]; then static_checks; fi
step "pytest, the ${tier} tier (hypothesis profile: ${HYPOTHESIS_PROFILE:-ci})"
# The gate draws the same examples on every run (tests/conftest.py, profile "ci");
# HYPOTHESIS_PROFILE=dev explores new ones.
if [ -n "$marker" ]; then
  HYPOTHESIS_PROFILE="${HYPOTHESIS_PROFILE:-ci}" python -m pytest -q -m "$marker" "$@"
else
  HYPOTHESIS_PROFILE="${HYPOTHESIS_PROFILE:-ci}" python -m pytest -q "$@"
fi
step "done, the ${tier} tier"
