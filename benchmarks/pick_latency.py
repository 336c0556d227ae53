"""Frame -> first robot command latency of the whole pick loop (target: <= 60 ms outside
the robot's own motion; thesis: 5.59 s on a laptop).

    python benchmarks/pick_latency.py [--model m.onnx ...] [--cycles 20] [--threads 2] [--out FILE.md | --save]

Synthetic 640x480 frames from a camera over a calibrated cell, the pick loop with SimRobot
(its motion takes no wall time, so what is measured is perception, target choice, planning,
the envelope checks and issuing the first command). Without --model, untrained default
models are exported at 640x480 and 320x240 and quantized (static int8): latency does not
depend on the weights. One process, the same frames for every model.
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import sys
import tempfile
from pathlib import Path

import numpy as np
import onnxruntime as ort

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from _common import add_output, emit, machine_line, untrained_checkpoint  # noqa: E402

from edgepick.data.render import CLASSES  # noqa: E402
from edgepick.geometry import Size  # noqa: E402
from edgepick.robot.grippers import DigitalGripper  # noqa: E402
from edgepick.robot.loop import run_cycles  # noqa: E402
from edgepick.robot.pick import CommandLog, PickConfig  # noqa: E402
from edgepick.runtime.pipeline import Pipeline  # noqa: E402
from edgepick.runtime.session import Segmenter  # noqa: E402
from edgepick.sim.camera import SynthCamera  # noqa: E402
from edgepick.sim.robot import SimRobot  # noqa: E402


def default_models(work: Path) -> list[str]:
    from edgepick.data.synth import SynthConfig, synthesize
    from edgepick.quant.passes import folder_images, quantize_static

    data = work / "data"
    synthesize(data, SynthConfig(scenes=20, seed=3, splits=(16, 2, 2)), progress=False)
    out = []
    for size in (Size(640, 480), Size(320, 240)):
        ckpt = untrained_checkpoint(work / f"untrained_{size.height}.pt", size, list(CLASSES))
        out.append(quantize_static(ckpt, folder_images(data, "train", 16), work / f"int8_{size.height}x{size.width}.onnx",
                                   progress=False).out)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", action="append", default=None)
    ap.add_argument("--cycles", type=int, default=20)
    ap.add_argument("--threads", type=int, default=2)
    add_output(ap)
    args = ap.parse_args()
    work = Path(tempfile.mkdtemp(prefix="pick-latency-"))
    rows = {}
    try:
        models = args.model or default_models(work)
        for path in models:
            camera = SynthCamera(seed=100, mount_height_m=0.7)
            pipeline = Pipeline(Segmenter(path, threads=args.threads), camera.calibration())
            with camera, SimRobot() as robot:
                run_cycles(camera, pipeline, robot, DigitalGripper(robot, 0), cfg=PickConfig(), cycles=2,
                           log=CommandLog(None), echo=lambda line: None)  # warm-up
                results = run_cycles(camera, pipeline, robot, DigitalGripper(robot, 0), cfg=PickConfig(),
                                     cycles=args.cycles, log=CommandLog(None), echo=lambda line: None)
            issued = [r["frame_to_command_ms"] for r in results if "frame_to_command_ms" in r]
            planned = [r["plan_ms"] for r in results]
            rows[Path(path).name] = {
                "input": pipeline.segmenter.info.input_size, "cycles": len(results), "picked": len(issued),
                "plan_p50": statistics.median(planned), "plan_p95": float(np.percentile(planned, 95)),
                "cmd_p50": statistics.median(issued) if issued else None,
                "infer_p50": statistics.median(r["stage_ms"]["inference"] for r in results),
                "motion_s": statistics.median(r["motion_s"] for r in results if "motion_s" in r) if issued else None}
    finally:
        shutil.rmtree(work, ignore_errors=True)

    lines = [f"# Pick loop: frame -> first command latency, {args.threads} onnxruntime threads", "",
             f"Command: `python benchmarks/pick_latency.py {' '.join(sys.argv[1:])}`  ",
             f"{machine_line()}; onnxruntime "
             f"{ort.__version__}; synthetic 640x480 frames, SimRobot; {args.cycles} cycles after 2 warm-up, one process.",
             "", "| Model (input) | cycles | with a target | inference p50 (ms) | frame -> plan p50 (ms) | p95 (ms) "
             "| frame -> first command p50 (ms) | simulated motion per cycle (s) |", "|---|---|---|---|---|---|---|---|"]
    for name, r in rows.items():
        cmd = "-" if r["cmd_p50"] is None else f"{r['cmd_p50']:.1f}"
        motion = "-" if r["motion_s"] is None else f"{r['motion_s']:.1f}"
        lines.append(f"| {name} ({r['input']}) | {r['cycles']} | {r['picked']} | "
                     f"{r['infer_p50']:.1f} | {r['plan_p50']:.1f} | {r['plan_p95']:.1f} | {cmd} | {motion} |")
    lines += ["", "Frame -> plan covers perception (pre, inference, post, grasp), target choice, planning and the",
              "envelope check of every pose; frame -> first command adds issuing the first moveL. Thesis: 5.59 s.",
              "Target: <= 60 ms."]
    report = "\n".join(lines) + "\n"
    emit(report, args)


if __name__ == "__main__":
    main()
