#!/usr/bin/env bash
# Thesis Tables 5.5 / 5.6 on one GPU at the SHORT setting (edgepick/bench/table55.py: the thesis's
# 4000/1000/100 split at 640x480, 100 epochs of 160 images each), in parts that each take under
# 10 minutes on an H100, so the work can be split over several shorter jobs:
#
#   bash benchmarks/table55_gpu.sh WORK qat      # synthetic data, then QaT from scratch (alone on the GPU)
#   bash benchmarks/table55_gpu.sh WORK rest     # synthetic data, the float run (alone on the GPU), then the
#                                                # fp32 export, static PTQ and the three hybrid-QaT runs in
#                                                # parallel (4 processes, 4 CPU threads each), then the bench
#   bash benchmarks/table55_gpu.sh WORK ab       # no table: the float run, hybrid-QaT 10% with the defaults and
#                                                # two variants (AB below), each scored on the test split
#   bash benchmarks/table55_gpu.sh WORK rest+ab  # both of the above from one float run
#
# The variants of hybrid-QaT 10% in AB: "firstbatch" starts the activation ranges from the first
# training batch's min/max and lets them move (--calib-images 0), "wexact" uses each step's own weight
# range (--weight-averaging 1.0); docs/quantization.md#hybrid-qat says why the defaults differ. Their
# test-split scores land in WORK/ab/*.eval.json, beside the float run's best.pt ("float") and last
# epoch ("float-last").
#
# The parts share WORK, or the second part is given WORK/models/qat.onnx and WORK/phases.json from the
# first (the synthetic data is deterministic, so each part makes it again). Phase wall times land in
# WORK/phases.json; the table in benchmarks/results/table55/<date>-<gpu>-short.md.
#
# On a machine without network access, install torchao from a wheel downloaded beforehand
# (pip download --no-deps --only-binary=:all: torchao) and put it on PYTHONPATH.
set -euo pipefail
work=${1:?usage: table55_gpu.sh WORK qat|rest|ab|rest+ab}
part=${2:?usage: table55_gpu.sh WORK qat|rest|ab|rest+ab}
t=("${PYTHON:-python3}" benchmarks/table55.py --setting short --work "$work")
AB=("firstbatch 0.10 --calib-images 0" "wexact 0.10 --weight-averaging 1.0")  # name, QaT fraction, options
case $part in
  qat)
    "${t[@]}" --only synth
    "${t[@]}" --only qat ;;
  rest|rest+ab|ab)
    "${t[@]}" --only synth
    "${t[@]}" --only float
    pids=()
    [[ $part == ab ]] || { OMP_NUM_THREADS=4 "${t[@]}" --only fp32,static & pids+=($!); }
    for p in 0.10 0.05 0.01; do
      [[ $part == ab && $p != 0.10 ]] || { OMP_NUM_THREADS=4 "${t[@]}" --only "hybrid$p" & pids+=($!); }
    done
    if [[ $part != rest ]]; then
      mkdir -p "$work/ab"
      for variant in "${AB[@]}"; do
        set -- $variant
        OMP_NUM_THREADS=2 "${PYTHON:-python3}" -m edgepick quantize hybrid "$work/float" --data "$work/data" \
          --qat-fraction "$2" "${@:3}" --out "$work/ab/$1-$2.onnx" >"$work/ab/$1-$2.quantize.json" & pids+=($!)
      done
    fi
    for pid in "${pids[@]}"; do wait "$pid"; done
    [[ $part == ab ]] || "${t[@]}" --only bench
    if [[ $part != rest ]]; then
      for f in "$work"/ab/*.onnx "$work"/models/hybrid0.10.onnx "$work/float" "$work/float/last.pt"; do
        name=$(basename "$f" .onnx); [[ $f == */last.pt ]] && name=float-last  # best.pt vs the last epoch
        "${PYTHON:-python3}" -m edgepick eval "$f" "$work/data" --split test --out "$work/ab/$name.eval.json" >/dev/null
      done
    fi ;;
  *) echo "part must be qat, rest, ab or rest+ab, got $part" >&2; exit 2 ;;
esac
