#!/usr/bin/env bash
# The recipe of the reference int8 model shipped in edgepick/reference/ (its MODEL_CARD.md):
# synthetic data, a float run at 320x240 on CPU, static and hybrid-QaT int8, test-split metrics.
#
#   bash benchmarks/reference_model.sh [WORK]      # WORK defaults to reference-run/
#
# About an hour on a 2-core CPU (the float run: 45 epochs of 400 images, ~60 s each). On a GPU,
# DEVICE=cuda, and the thesis's scale is within reach: e.g. DEVICE=cuda EPOCHS=100 EPOCH_IMAGES=0
# SIZE=640x480 (the hybrid switch point stays at 95% of the epochs). Then Table 5.6 in the cell:
#   python benchmarks/table56.py --models WORK/models/fp32.onnx WORK/models/static.onnx WORK/models/hybrid.onnx --save
set -euo pipefail
WORK=${1:-reference-run}
EP=${EDGEPICK:-edgepick}
DEVICE=${DEVICE:-cpu}
EPOCHS=${EPOCHS:-45}
EPOCH_IMAGES=${EPOCH_IMAGES:-400}
SIZE=${SIZE:-320x240}
KEEP="$((EPOCHS * 9 / 10)),$((EPOCHS - EPOCHS / 20)),$((EPOCHS - 1))"
mkdir -p "$WORK/models"
[ -d "$WORK/data" ] || $EP data synth "$WORK/data" --splits 2000,200,100 --seed 11
[ -f "$WORK/float/last.pt" ] || $EP train "$WORK/data" --out "$WORK/float" --epochs "$EPOCHS" \
    --epoch-images "$EPOCH_IMAGES" --val-images 100 --batch-size 8 --size "$SIZE" --lr 2e-3 --device "$DEVICE" \
    --keep-epochs "$KEEP" --seed 0
$EP export "$WORK/float" --out "$WORK/models/fp32.onnx"
$EP quantize static "$WORK/float" --data "$WORK/data" --out "$WORK/models/static.onnx"
$EP quantize hybrid "$WORK/float" --data "$WORK/data" --qat-fraction 0.05 --device "$DEVICE" \
    --out "$WORK/models/hybrid.onnx"
for m in fp32 static hybrid; do
    $EP eval "$WORK/models/$m.onnx" "$WORK/data" --split test --out "$WORK/models/$m-test.json" > /dev/null
done
