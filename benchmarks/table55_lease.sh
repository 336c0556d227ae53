#!/usr/bin/env bash
# Thesis Tables 5.5 / 5.6 at the LEASE setting (edgepick/bench/table55.py: the thesis's 4000/1000/100
# split at 480x640, 100 epochs of 160 images) on one GPU, in two parts that each fit a 10-minute call:
#
#   bash benchmarks/table55_lease.sh WORK qat    # synth, then QaT from scratch (alone on the GPU)
#   bash benchmarks/table55_lease.sh WORK rest   # synth, the float run (alone on the GPU), then fp32
#                                                # export + static PTQ and the three hybrid-QaT runs in
#                                                # parallel (4 processes, 4 CPU threads each), then the bench
#   bash benchmarks/table55_lease.sh WORK rest+ab  # rest, and beside the three hybrid runs variants of
#                                                # hybrid-QaT 10% from the same float run (AB below; session 8
#                                                # ran "fresh --fresh-optimizer" and "nofreeze --freeze-at 1.0");
#                                                # their test-split scores land in WORK/ab/*.eval.json, with the
#                                                # float run's best.pt (float) and last epoch (float-last)
#   bash benchmarks/table55_lease.sh WORK ab     # the A/B alone, no table (not run yet; ~8 min by call 2's phase times;
#                                                # rest+ab took 9.3 min and rest alone once ran past 9 min):
#                                                # synth, float run, hybrid-QaT 10% and its variants, test evals
#
# AB's variants of hybrid-QaT 10%: "firstbatch" is the default before session 10 (activation ranges from
# the first batch's min/max, moving), which lost 1.2-2.2 pp on the GPU; a CPU model at 240x320 lost 1-2.7
# pp with it and 0.1-0.8 pp (test) with today's default (percentile ranges from 64 images, held).
#
# On the leased device machine (torch with CUDA, onnxruntime, no torchao, no network): download the torchao
# wheel here first (`pip download --no-deps --only-binary=:all: --python-version 3.12 --implementation cp
# --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64
# -d .whl torchao==0.18.0`, .whl/ kept out of git), carry .whl, and start
# each call with `pip install -q --no-index --no-deps --target /tmp/site .whl/*.whl &&
# export PYTHONPATH=/tmp/site:$PWD`; keep each part under the call's 10 minutes (timeout ~545 s) and copy
# WORK's logs, metrics.json files and phases.json to $OUT.
#
# Both parts use the same WORK folder or carry WORK/models/qat.onnx and WORK/phases.json from the
# first to the second (the synthetic data is deterministic, so each part makes it again).
# Phase wall times land in WORK/phases.json; the table in benchmarks/results/table55-<machine>-lease.md.
set -euo pipefail
work=${1:?usage: table55_lease.sh WORK qat|rest|rest+ab|ab}
part=${2:?usage: table55_lease.sh WORK qat|rest|rest+ab|ab}
t=("${PYTHON:-python3}" benchmarks/table55.py --setting lease --work "$work")
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
  *) echo "part must be qat, rest, rest+ab or ab, got $part" >&2; exit 2 ;;
esac
