#!/usr/bin/env bash
# The GPU training call, dry-run here on the CPU (issue 22: "dry-run it on the CPU for one epoch
# first"): the same module and steps as scripts/gpu/train_sim.sh, with the packages the device
# lacks hidden (device_like.py), a few images a shard and one epoch.
#   bash scripts/gpu/dry_run_cpu.sh OUT_DIR
set -euo pipefail
cd "$(dirname "$0")/../.."
out=${1:?usage: dry_run_cpu.sh OUT_DIR}
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
py=${PYTHON:-python3}
# The source tree when it holds the built extension (a `maturin develop` checkout, as the device
# gets it carried); else the installed package (CI tests the wheel; its tree has no _core).
if compgen -G "python/insulator_rs/_core*.so" >/dev/null; then
  export PYTHONPATH="$PWD/python${PYTHONPATH:+:$PYTHONPATH}"
fi
PYTHONUNBUFFERED=1 \
  "$py" scripts/gpu/device_like.py insulator_rs.app.gpu_training --out "$out" --work "$work/w" \
  --device cpu --shards 2 --tower-views-per-shard 6 --steel-views-per-shard 6 --val-views 6 \
  --steel-test-views 6 --batch 8 --workers 0 --epochs 1 --fixed-epochs --deadline-s 900 --reserve-s 300 "${@:2}"
