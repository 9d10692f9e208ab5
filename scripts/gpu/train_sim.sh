#!/usr/bin/env bash
# Runs ON the lent GPU machine (the device tool's `run`, from the repository root), after
# scripts/gpu/stage.sh here: renders insulator-sim's training set on the machine's CPUs, trains
# on its GPU, exports the ONNX and measures it (python -m insulator_rs.app.gpu_training).
# Everything it writes lands in $OUT: insulator-sim.onnx, insulator-sim_best.pt, results.csv,
# training.png, summary.json, gpu.txt and log.txt (7 of the 8 files a call may return).
# DEADLINE_S (default 540) bounds the work inside the call's 600 s; GPU_TRAINING_ARGS adds
# recipe options (see `python -m insulator_rs.app.gpu_training --help`).
set -euo pipefail
: "${OUT:?OUT is unset: this script runs on the device machine, which sets it}"
cd "$(dirname "$0")/../.."
ls .whl/*.whl >/dev/null 2>&1 || { echo "train_sim: no .whl/: run scripts/gpu/stage.sh here and carry .whl" >&2; exit 1; }
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl
export PYTHONPATH="/tmp/site:$PWD/python" PYTHONUNBUFFERED=1
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv | tee "$OUT/gpu.txt"
python3 -c "import insulator_rs._core, torch; assert torch.cuda.is_available(), 'no CUDA'; print('torch', torch.__version__)"
# shellcheck disable=SC2086  # GPU_TRAINING_ARGS is split on purpose
python3 -m insulator_rs.app.gpu_training --out "$OUT" --work /tmp/gpu_work \
  --deadline-s "${DEADLINE_S:-540}" ${GPU_TRAINING_ARGS:-} 2>&1 | tee "$OUT/log.txt"
