#!/usr/bin/env bash
# The recipe of the reference int8 model shipped in edgepick/reference/ (its MODEL_CARD.md):
# synthetic data, a float run on one GPU at 640x480, static and hybrid-QaT int8, test-split metrics.
# The shipped file is WORK/models/static.onnx.
#
#   bash benchmarks/reference_model.sh [WORK]      # WORK defaults to reference-run/
#
# On one H100 the data, the float run (45 epochs of 4000 scenes, ~14.5 s each) and static PTQ take
# about 12 minutes; hybrid-QaT then trains two QaT epochs. Every setting is an environment variable. Without a
# GPU, a smaller run fits in an hour on 2 cores and picks far worse (MODEL_CARD.md, "Limits"):
#   DEVICE=cpu EPOCHS=45 EPOCH_IMAGES=400 SIZE=320x240 SPLITS=2000,200,100 BATCH=8 bash benchmarks/reference_model.sh
# Then Table 5.6 in the cell:
#   python benchmarks/table56.py --models WORK/models/fp32.onnx WORK/models/static.onnx WORK/models/hybrid.onnx --save
set -euo pipefail
WORK=${1:-reference-run}
EP=${EDGEPICK:-edgepick}
DEVICE=${DEVICE:-cuda}
EPOCHS=${EPOCHS:-45}
EPOCH_IMAGES=${EPOCH_IMAGES:-0}  # 0: the whole train split each epoch
SIZE=${SIZE:-640x480}
SPLITS=${SPLITS:-4000,200,100}  # train,val,test scenes
BATCH=${BATCH:-16}
KEEP="$((EPOCHS * 9 / 10)),$((EPOCHS - EPOCHS / 20)),$((EPOCHS - 1))"
mkdir -p "$WORK/models"
[ -d "$WORK/data" ] || $EP data synth "$WORK/data" --splits "$SPLITS" --seed 11
[ -f "$WORK/float/last.pt" ] || $EP train "$WORK/data" --out "$WORK/float" --epochs "$EPOCHS" \
    --epoch-images "$EPOCH_IMAGES" --val-images 100 --batch-size "$BATCH" --size "$SIZE" --lr 2e-3 --device "$DEVICE" \
    --keep-epochs "$KEEP" --seed 0
$EP export "$WORK/float" --out "$WORK/models/fp32.onnx"
$EP quantize static "$WORK/float" --data "$WORK/data" --out "$WORK/models/static.onnx"
test_eval() { $EP eval "$WORK/models/$1.onnx" "$WORK/data" --split test --out "$WORK/models/$1-test.json" > /dev/null; }
test_eval fp32
test_eval static
$EP quantize hybrid "$WORK/float" --data "$WORK/data" --qat-fraction 0.05 --device "$DEVICE" \
    --out "$WORK/models/hybrid.onnx"
test_eval hybrid
