#!/usr/bin/env bash
# The recipe of the reference int8 model shipped in edgepick/reference/ (its MODEL_CARD.md):
# synthetic data, a float run at 320x240 on CPU, static and hybrid-QaT int8, test-split metrics.
#
#   bash benchmarks/reference_model.sh [WORK]      # WORK defaults to reference-run/
#
# About an hour on a 2-core CPU (the float run: 45 epochs of 400 images, ~60 s each), minutes on
# a GPU (add --device cuda, or leave the default auto). Then Table 5.6 in the synthetic cell:
#   python benchmarks/table56.py --models WORK/models/fp32.onnx WORK/models/static.onnx WORK/models/hybrid.onnx --save
set -euo pipefail
WORK=${1:-reference-run}
EP=${EDGEPICK:-edgepick}
DEVICE=${DEVICE:-cpu}
mkdir -p "$WORK/models"
[ -d "$WORK/data" ] || $EP data synth "$WORK/data" --splits 2000,200,100 --seed 11
[ -f "$WORK/float/last.pt" ] || $EP train "$WORK/data" --out "$WORK/float" --epochs 45 --epoch-images 400 \
    --val-images 100 --batch-size 8 --size 320x240 --lr 2e-3 --device "$DEVICE" --keep-epochs 40,43,44 --seed 0
$EP export "$WORK/float" --out "$WORK/models/fp32.onnx"
$EP quantize static "$WORK/float" --data "$WORK/data" --out "$WORK/models/static.onnx"
$EP quantize hybrid "$WORK/float" --data "$WORK/data" --qat-fraction 0.05 --device "$DEVICE" \
    --out "$WORK/models/hybrid.onnx"
for m in fp32 static hybrid; do
    $EP eval "$WORK/models/$m.onnx" "$WORK/data" --split test --out "$WORK/models/$m-test.json" > /dev/null
done
