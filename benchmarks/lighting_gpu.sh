#!/usr/bin/env bash
# Does `train --augment lights` make the weak light conditions pick better? Four float runs on one
# GPU at the same time, from one data set: --augment basic and lights, each with seeds 0 and 1 (the
# seed spread is the noise the difference must clear), then each one's static int8 file.
#
#   bash benchmarks/lighting_gpu.sh WORK OUT
#
# OUT receives basic-s0.onnx, basic-s1.onnx, lights-s0.onnx, lights-s1.onnx and runs.tar.gz (each
# run's metrics.json and each pass's JSON). The grasp success per light condition is then measured on
# a CPU, on the same cell cycles for every file:
#
#   python benchmarks/lighting_augment.py OUT/*.onnx --save
#
# The runs are shorter than the reference recipe (EPOCHS x EPOCH_IMAGES images instead of 45 x 4000).
# TRAIN_SECONDS stops the training where a job has a time limit: the files are then made from each
# run's best epoch so far. Run the same command again (same WORK) to resume the runs from their
# last.pt and make the files again (training times: benchmarks/results/lighting-augment/).
set -euo pipefail
work=${1:?usage: lighting_gpu.sh WORK OUT}
out=${2:?usage: lighting_gpu.sh WORK OUT}
py=${PYTHON:-python3}
DEVICE=${DEVICE:-cuda}
EPOCHS=${EPOCHS:-16}
EPOCH_IMAGES=${EPOCH_IMAGES:-2000}
SIZE=${SIZE:-640x480}
SPLITS=${SPLITS:-4000,200,100}
TRAIN_SECONDS=${TRAIN_SECONDS:-330}
mkdir -p "$work" "$out"
[ -d "$work/data" ] || "$py" -m edgepick data synth "$work/data" --splits "$SPLITS" --seed 11 >"$work/synth.json"
runs=()
for augment in basic lights; do
  for seed in 0 1; do
    name=$augment-s$seed; runs+=("$name")
    if [ -f "$work/$name/last.pt" ]; then
      args=(--resume)
    else
      args=(--epochs "$EPOCHS" --epoch-images "$EPOCH_IMAGES" --val-images 100 --batch-size 16 --size "$SIZE" \
            --lr 2e-3 --device "$DEVICE" --seed "$seed" --augment "$augment")
    fi
    OMP_NUM_THREADS=4 timeout --signal=INT "$TRAIN_SECONDS" "$py" -m edgepick train "$work/data" --out "$work/$name" \
      "${args[@]}" >"$work/$name.train.json" 2>>"$work/$name.train.log" &
  done
done
wait || true  # a run stopped by TRAIN_SECONDS keeps its best epoch
for name in "${runs[@]}"; do
  OMP_NUM_THREADS=4 "$py" -m edgepick quantize static "$work/$name" --data "$work/data" --out "$out/$name.onnx" \
    >"$work/$name.static.json" 2>"$work/$name.static.log" &
done
wait
tar -czf "$out/runs.tar.gz" -C "$work" $(cd "$work" && ls ./*.json ./*.log ./*/metrics.json)
