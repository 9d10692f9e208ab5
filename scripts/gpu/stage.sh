#!/usr/bin/env bash
# Prepare the GPU training call here, before a GPU machine is lent (issue 22):
#   bash scripts/gpu/stage.sh
# 1. the wheels of scripts/gpu/requirements.txt for the device's Python (3.12, x86-64) into .whl/
# 2. the Rust extension (python/insulator_rs/_core.abi3.so, x86-64, abi3) built in place
# 3. the size that will travel (tracked tree + carried paths) checked against the 64 MiB limit
# and then prints the one device call to make.
set -euo pipefail
cd "$(dirname "$0")/../.."
py=${PYTHON:-python3}
mkdir -p .whl
"$py" -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
  --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 \
  -d .whl -r scripts/gpu/requirements.txt
if [ ! -f python/insulator_rs/_core.abi3.so ]; then
  [ "$(uname -m)" = x86_64 ] || { echo "stage: build the extension on x86-64 (the device's CPU)" >&2; exit 1; }
  "$py" -m maturin develop --release
fi
limit=$((64 * 1024 * 1024))
tree=$(git ls-files -z | xargs -0 stat -c %s | awk '{s += $1} END {print s}')
carried=$(du -cb .whl python/insulator_rs/_core.abi3.so | tail -1 | cut -f1)
total=$((tree + carried))
echo "travels: tracked tree $tree B + carried $carried B = $total B of $limit"
if [ "$total" -gt "$limit" ]; then
  echo "stage: $((total - limit)) B over the device's 64 MiB: carry less" >&2
  exit 1
fi
cat <<'CALL'
the device call (run), one of at most 10 minutes:
  command:   bash scripts/gpu/train_sim.sh
  carry:     [".whl", "python/insulator_rs/_core.abi3.so"]
  timeout_s: 600
then, here, with the files it returns in FILES (the card's test split, rendered bit for bit):
  insulator-rs dataset --out simdata --images 1500 --seed 6
  insulator-rs detect eval simdata/images/test --model FILES/insulator-sim.onnx
  insulator-rs dataset --steel-views --images 400 --split 0 0 1 --seed 4 --out steel_test
  insulator-rs detect false-boxes steel_test --model FILES/insulator-sim.onnx
and the model card, the README and issue 22 with what it measured.
CALL
