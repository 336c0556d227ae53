"""How long must alternating timing blocks wait between two onnxruntime sessions?

onnxruntime's worker threads keep spinning for a while after a run. On a 2-core laptop a session
timed in a block right after another session's block shares the cores with those threads, and a
small model's time then says more about the other session than about itself. This script times
a float model and its int8 file one after the other, then in alternating blocks (`interleaved_times`) with
several pauses before each block, and reports the p50s and the int8 speed-up of each: the pause
every edgepick timing uses (`edgepick.runtime.session.SWITCH_PAUSE_S`) is the one whose figures
match the models timed one after the other. Without --onnx the models are made here: a small conv net (about
2 ms in int8 on 2 cores, where the effect is largest) and its `quantize_onnx_static` file.

    python benchmarks/session_switch.py --save
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from _common import add_output, emit, machine_line  # noqa: E402

import edgepick.runtime.session as session  # noqa: E402


def small_net(path: Path, size: int = 112, channels: int = 32, convs: int = 6) -> Path:
    """A float ONNX stack of 3x3 convs and Relus on a SIZE x SIZE image, seeded."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    rng = np.random.default_rng(0)
    nodes, inits, prev, cin = [], [], "image", 3
    for k in range(convs):
        w = rng.normal(0, (2 / (9 * cin)) ** 0.5, (channels, cin, 3, 3)).astype(np.float32)
        inits += [numpy_helper.from_array(w, f"w{k}"), numpy_helper.from_array(np.zeros(channels, np.float32), f"b{k}")]
        nodes += [helper.make_node("Conv", [prev, f"w{k}", f"b{k}"], [f"c{k}"], pads=[1, 1, 1, 1], name=f"conv{k}"),
                  helper.make_node("Relu", [f"c{k}"], [f"r{k}"], name=f"relu{k}")]
        prev, cin = f"r{k}", channels
    graph = helper.make_graph(nodes, "small", [helper.make_tensor_value_info("image", TensorProto.FLOAT, [1, 3, size, size])],
                              [helper.make_tensor_value_info(prev, TensorProto.FLOAT, [1, channels, size, size])], inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])
    model.ir_version = 8
    onnx.save(model, str(path))
    return path


def runner(path: Path, threads: int):
    """PATH as onnxruntime runs it in edgepick (session.plain_session), on one fixed input."""
    sess = session.plain_session(path, threads)
    inp = sess.get_inputs()[0]
    x = np.random.default_rng(1).random([d if isinstance(d, int) else 1 for d in inp.shape], dtype=np.float32)
    return lambda i: sess.run(None, {inp.name: x})


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--onnx", default=None, help="two ONNX files, comma-separated, the first the reference "
                                                 "[default: a small conv net made here and its int8 file]")
    ap.add_argument("--pauses", default="0,0.02,0.1", help="seconds before each block, comma-separated")
    ap.add_argument("--runs", type=int, default=40, help="timed runs per model and setting")
    ap.add_argument("--threads", type=int, default=2)
    add_output(ap)
    args = ap.parse_args(argv)
    pauses = [float(p) for p in args.pauses.split(",") if p]
    with tempfile.TemporaryDirectory() as tmp:
        if args.onnx:
            paths = [Path(p) for p in args.onnx.split(",")]
            if len(paths) != 2:
                ap.error("--onnx: two files")
        else:
            from edgepick.quant.onnx.static import quantize_onnx_static

            fp32 = small_net(Path(tmp) / "fp32.onnx")
            calib = [np.random.default_rng(k).random((1, 3, 112, 112), dtype=np.float32) for k in range(8)]
            paths = [fp32, Path(quantize_onnx_static(fp32, calib, Path(tmp) / "int8.onnx", progress=False).out)]
        rows, pause = [], session.SWITCH_PAUSE_S
        try:
            for setting in ["alone", *pauses]:
                calls = [runner(p, args.threads) for p in paths]
                if setting == "alone":  # each model in one stretch of runs, then the other
                    p50 = [statistics.median(session.interleaved_times([c], args.runs)[0]) for c in calls]
                else:
                    session.SWITCH_PAUSE_S = setting
                    p50 = [statistics.median(t) for t in session.interleaved_times(calls, args.runs)]
                del calls
                rows.append((setting, p50))
        finally:  # every other timing in this process keeps edgepick's pause
            session.SWITCH_PAUSE_S = pause
    names = [p.name for p in paths]
    lines = ["# Alternating timing blocks: the pause between two onnxruntime sessions", "",
             f"Command: `python benchmarks/session_switch.py {' '.join(argv if argv is not None else sys.argv[1:])}`".rstrip()
             + "  ", f"{machine_line()}; onnxruntime {session.ort.__version__}, {args.threads} threads", "",
             f"Models: {', '.join(names)}" + ("" if args.onnx else " (a 6-conv 32-channel net at 112x112, made here, and "
                                                                  "its `quantize_onnx_static` file)"), "",
             f"p50 over {args.runs} timed runs per model: first each model in one stretch of runs, then the two "
             "in alternating blocks of 5 with the pause before each block; the speed-up is the first model's p50 over "
             "the second's.", "",
             f"| pause before each block | {names[0]} p50 (ms) | {names[1]} p50 (ms) | speed-up |", "|---|---|---|---|"]
    for setting, (a, b) in rows:
        label = "none: one model after the other" if setting == "alone" else f"{setting:g} s"
        lines.append(f"| {label} | {a:.2f} | {b:.2f} | {a / b:.2f}x |")
    emit("\n".join(lines) + "\n", args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
