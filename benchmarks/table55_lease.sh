#!/usr/bin/env bash
# Thesis Tables 5.5 / 5.6 at the LEASE setting (edgepick/bench/table55.py: the thesis's 4000/1000/100
# split at 480x640, 100 epochs of 160 images) on one GPU, in two parts that each fit a 10-minute call:
#
#   bash benchmarks/table55_lease.sh WORK qat    # synth, then QaT from scratch (alone on the GPU)
#   bash benchmarks/table55_lease.sh WORK rest   # synth, the float run (alone on the GPU), then fp32
#                                                # export + static PTQ and the three hybrid-QaT runs in
#                                                # parallel (4 processes, 4 CPU threads each), then the bench
#
# Both parts use the same WORK folder or carry WORK/models/qat.onnx and WORK/phases.json from the
# first to the second (the synthetic data is deterministic, so each part makes it again).
# Phase wall times land in WORK/phases.json; the table in benchmarks/results/table55-<machine>-lease.md.
set -euo pipefail
work=${1:?usage: table55_lease.sh WORK qat|rest}
part=${2:?usage: table55_lease.sh WORK qat|rest}
t=("${PYTHON:-python3}" benchmarks/table55.py --setting lease --work "$work")
case $part in
  qat)
    "${t[@]}" --only synth
    "${t[@]}" --only qat ;;
  rest)
    "${t[@]}" --only synth
    "${t[@]}" --only float
    pids=()
    OMP_NUM_THREADS=4 "${t[@]}" --only fp32,static & pids+=($!)
    for p in 0.10 0.05 0.01; do OMP_NUM_THREADS=4 "${t[@]}" --only "hybrid$p" & pids+=($!); done
    for pid in "${pids[@]}"; do wait "$pid"; done
    "${t[@]}" --only bench ;;
  *) echo "part must be qat or rest, got $part" >&2; exit 2 ;;
esac
