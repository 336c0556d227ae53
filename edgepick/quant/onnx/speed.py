"""How fast the int8 file runs against the float model on this machine, recorded with the file.

Whether int8 pays depends on the CPU as much as on the model: onnxruntime's int8 convs gain most
where the CPU adds int8 products in int32 (AVX-512 VNNI, AVX-VNNI, AMX); on a CPU with AVX2 alone
they add them in int16 pairs first, and four of the 16 conformance models' int8 files ran slower
than fp32 there (benchmarks/results/conformance/, the AVX2 run). So the static pass times both files
on onnxruntime on this machine (alternating blocks, p50, the runtime's two threads), records the
times in the file's quant record, and says in one line where the int8 file is clearly the slower
one: on such a CPU the float model, or OpenVINO (`--placement auto --target openvino`), can serve a
user better.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from edgepick.machine import cpu_summary

TIMED_RUNS = 20  # per file, in alternating blocks
TIMING_THREADS = 2  # as the runtime and the benchmarks run a model on a laptop
# the warning's threshold: on a shared machine the ratio of two files' times moves by 0.1 or more from run to run
SLOWER_BELOW = 0.9


def ort_runner(model: Any, threads: int = TIMING_THREADS) -> Callable[[np.ndarray], object]:
    """A function running MODEL (an ONNX ModelProto, or the path of a file) on onnxruntime's CPU
    provider with THREADS threads."""
    import onnxruntime as ort

    opts = ort.SessionOptions()
    opts.intra_op_num_threads, opts.inter_op_num_threads, opts.log_severity_level = threads, 1, 3
    source = str(model) if isinstance(model, (str, Path)) else model.SerializeToString()
    session = ort.InferenceSession(source, opts, providers=["CPUExecutionProvider"])
    name = session.get_inputs()[0].name
    return lambda image: session.run(None, {name: image})


def speed_against_fp32(float_model: Any, int8: Any, x: np.ndarray, threads: int = TIMING_THREADS) -> dict:
    """onnxruntime's median ms of FLOAT_MODEL and the QDQ graph INT8 on the input X, timed in
    alternating blocks on THREADS threads, their ratio (`speedup_vs_fp32`) and the machine."""
    from edgepick.runtime.session import median_ms

    ms = median_ms({"fp32_ms": ort_runner(float_model, threads), "int8_ms": ort_runner(int8, threads)}, x,
                   timed=TIMED_RUNS)
    return {**ms, "speedup_vs_fp32": round(ms["fp32_ms"] / ms["int8_ms"], 3), "threads": threads,
            "machine": cpu_summary()}


def slower_than_fp32_warning(speed: dict) -> str | None:
    """The one-line warning where SPEED (`speed_against_fp32`'s record) has the int8 file slower than
    the float model by more than the timing's noise (under SLOWER_BELOW of its speed); else None."""
    if speed["speedup_vs_fp32"] >= SLOWER_BELOW:
        return None
    return (f"the int8 file runs at {speed['speedup_vs_fp32']:.2f}x fp32's speed on onnxruntime on this machine "
            f"({speed['int8_ms']:g} ms against {speed['fp32_ms']:g} ms, {speed['threads']} threads; "
            f"{speed['machine']}): here the float model serves better, or OpenVINO (--placement auto --target openvino) may")
