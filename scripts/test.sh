#!/usr/bin/env bash
# The project's test command (README). Run from the repository root inside the venv.
#
#   bash scripts/test.sh          the quick tier, before every commit (at most 5 minutes on a
#                                 2-core machine): the Rust crates' tests, the stub check and mypy
#                                 (beside pytest), and
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

# pytest-xdist workers (PYTEST_WORKERS, default 3; 0: none). Most tests wait on sockets and
# simulated clocks, not on the CPU: on this 2-core kind three workers take the quick tier's pytest
# from 4.4 to 1.5 minutes. tests/conftest.py keeps a module on one worker (its fixtures are built
# once) and the tests marked xdist_group together.
workers="${PYTEST_WORKERS:-3}"
xdist=()
if [ "$workers" != "0" ]; then xdist=(-n "$workers" --dist loadgroup); fi

# The Rust crates' tests compile for minutes on a clean clone, on the CPU the waiting pytest
# workers leave idle: they build and run beside the stub check, mypy and pytest, their output in
# a log printed at the end (the quick tier and --all; --slow is what they leave out).
cargo_log=""
cargo_pid=""
if [ "$tier" != "slow" ]; then
  cargo_log=$(mktemp)
  step "cargo test (fusion_core, scene_raycast, livox_mid360), beside the rest: output at the end"
  cargo test --quiet --release -p fusion_core -p scene_raycast -p livox_mid360 >"$cargo_log" 2>&1 &
  cargo_pid=$!
fi
# beside_wait LABEL PID LOG [SUMMARY]: wait for a job run beside pytest and print its log (with
# SUMMARY, an extended regex: only those lines, and the log's tail if it failed); its exit status.
beside_wait() {
  local label=$1 pid=$2 log=$3 summary=${4:-} rc=0
  [ -n "$pid" ] || return 0
  wait "$pid" || rc=$?
  step "$label: exit $rc"
  if [ -z "$summary" ]; then
    cat "$log"
  else
    grep -E "$summary" "$log" || true
    if [ "$rc" -ne 0 ]; then tail -60 "$log"; fi
  fi
  rm -f "$log"
  return "$rc"
}
# a failure below still reports (and stops) cargo's run
trap 'for pid in "$cargo_pid" "${typing_pid:-}"; do if [ -n "$pid" ]; then kill "$pid" 2>/dev/null || true; fi; done' EXIT

# The stub check and mypy (80-100 s on a clean clone, no cache) run beside pytest as cargo does:
# its workers spend most of the quick tier waiting on sockets and simulated clocks. Their output is
# printed at the end, and either failing fails the tier.
typing_log=""
typing_pid=""
if [ "$tier" != "slow" ]; then
  typing_log=$(mktemp)
  step "stub check (_core.pyi against the compiled module) then mypy, beside pytest: output at the end"
  (
    set -e
    echo "== stub check (_core.pyi against the compiled module)"
    python -m mypy.stubtest insulator_rs._core --allowlist scripts/stubtest_allowlist.txt
    if [ "${INSULATOR_RS_MYPY:-1}" = "1" ]; then
      echo "== mypy (python/insulator_rs; settings: pyproject.toml [tool.mypy])"
      python -m mypy
    else
      # numpy's stubs differ between the numpy pip picks for 3.10 and for 3.11 (the same code
      # types differently): CI gates mypy once, in its 3.11 venv
      echo "== mypy: not in this venv (INSULATOR_RS_MYPY=0)"
    fi
  ) >"$typing_log" 2>&1 &
  typing_pid=$!
fi
step "pytest, the ${tier} tier (hypothesis profile: ${HYPOTHESIS_PROFILE:-ci}; workers: ${workers})"
# The gate draws the same examples on every run (tests/conftest.py, profile "ci");
# HYPOTHESIS_PROFILE=dev explores new ones.
# Tests marked realtime (a sensor head rendering in real time beside a PX4 SITL, a clock judged
# against wall time) run after the rest, alone, in one process: beside two workers' flights a
# starved sensor head loses the flight, which says nothing of the code. pytest's exit 5 ("no
# tests collected": a tier or a file without such tests) is not a failure.
pytest_rc=0
selected="${marker:-}"
parallel="${selected:+($selected) and }not realtime"
alone="${selected:+($selected) and }realtime"
HYPOTHESIS_PROFILE="${HYPOTHESIS_PROFILE:-ci}" python -m pytest -q "${xdist[@]}" -m "$parallel" "$@" || pytest_rc=$?
if [ "$pytest_rc" -eq 5 ]; then pytest_rc=0; fi
# a -m among the arguments replaces the tier's marker (pytest takes the last): then one run only
own_marker=0
for arg in "$@"; do if [ "$arg" = "-m" ]; then own_marker=1; fi; done
if [ "$own_marker" = "0" ]; then
  step "pytest, the ${tier} tier's realtime tests, alone"
  alone_rc=0
  HYPOTHESIS_PROFILE="${HYPOTHESIS_PROFILE:-ci}" python -m pytest -q -m "$alone" "$@" || alone_rc=$?
  if [ "$alone_rc" -ne 5 ] && [ "$alone_rc" -ne 0 ]; then pytest_rc=$alone_rc; fi
fi
typing_rc=0
beside_wait "stub check and mypy" "$typing_pid" "$typing_log" || typing_rc=$?
typing_pid=""
cargo_rc=0
beside_wait "cargo test" "$cargo_pid" "$cargo_log" "^test result|FAILED|panicked|error(\[|:)" || cargo_rc=$?
cargo_pid=""
if [ "$pytest_rc" -ne 0 ] || [ "$cargo_rc" -ne 0 ] || [ "$typing_rc" -ne 0 ]; then
  step "failed: pytest exit $pytest_rc, cargo test exit $cargo_rc, stub check and mypy exit $typing_rc"
  exit 1
fi
step "done, the ${tier} tier"
