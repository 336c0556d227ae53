"""Frame -> first command latency of the whole pick loop in the synthetic cell, without and with
`pick --overlap` (target: frame -> first command p50 at most 5 ms above the inference p50).

    python benchmarks/pick_latency.py [--model m.onnx ...] [--engine onnxruntime|openvino] [--cycles 30]
                                      [--threads 2] [--realtime 0.25] [--out FILE.md | --save]

The synthetic cell's 640x480 frames (camera 0.7 m over the table, SimRobot, the reference model
by default): each cycle perceives (pre, inference, post, grasp), chooses a target, plans, checks
every pose against the envelope and issues the commands. SimRobot spends --realtime wall seconds
per simulated second of motion, as an arm's blocking moves would at that speed-up, so that
--overlap (the next frame read and segmented while the arm places and returns) has motion to hide
behind. One process, the same frames for every row.
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

import numpy as np
import onnxruntime as ort

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from _common import add_output, emit, machine_line  # noqa: E402

from edgepick.reference import reference_model  # noqa: E402
from edgepick.robot.grippers import DigitalGripper  # noqa: E402
from edgepick.robot.loop import Cell, run_cycles  # noqa: E402
from edgepick.robot.pick import CommandLog, PickConfig  # noqa: E402
from edgepick.runtime.engine import Engine  # noqa: E402
from edgepick.runtime.pipeline import Pipeline  # noqa: E402
from edgepick.runtime.session import Segmenter  # noqa: E402
from edgepick.sim.camera import SynthCamera  # noqa: E402
from edgepick.sim.robot import SimRobot  # noqa: E402


def p50(results: list[dict], key: str) -> float | None:
    values = [r[key] for r in results if key in r]
    return statistics.median(values) if values else None


def row(segmenter: Segmenter, cycles: int, overlap: bool, realtime: float) -> dict:
    """CYCLES cycles of the cell (seed 100) after 2 warm-up cycles, and their medians."""
    camera = SynthCamera(640, 480, seed=100, mount_height_m=0.7)
    pipeline = Pipeline(segmenter, camera.calibration())
    robot = SimRobot(realtime=realtime)
    with camera, robot:
        cell = Cell(camera, pipeline, robot, DigitalGripper(robot, 0), CommandLog(None))
        run_cycles(cell, cfg=PickConfig(), cycles=2, echo=lambda line: None)  # warm-up
        results = [r.to_dict() for r in run_cycles(cell, cfg=PickConfig(), cycles=cycles, echo=lambda line: None,
                                                    overlap=overlap)]
    return {"cycles": len(results), "picked": sum("frame_to_command_ms" in r for r in results),
            "inference": statistics.median(r["stage_ms"]["inference"] for r in results),
            "grasp": statistics.median(r["stage_ms"]["grasp"] for r in results),
            "plan": p50(results, "plan_ms"), "plan_p95": float(np.percentile([r["plan_ms"] for r in results], 95)),
            "command": p50(results, "frame_to_command_ms"), "frame": p50(results, "frame_to_frame_ms"),
            "wait": p50(results, "arm_wait_ms"), "motion": p50(results, "motion_s")}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", action="append", default=None, help="ONNX model(s) [default: the shipped reference model]")
    ap.add_argument("--engine", default=Engine.ONNXRUNTIME.value, choices=[Engine.ONNXRUNTIME.value, Engine.OPENVINO.value])
    ap.add_argument("--cycles", type=int, default=30)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--realtime", type=float, default=0.25,
                    help="SimRobot's wall seconds per simulated second of motion [default: 0.25]")
    add_output(ap)
    args = ap.parse_args()

    rows = {}
    for path in args.model or [str(reference_model())]:
        segmenter = Segmenter(path, threads=args.threads, engine=args.engine)
        for overlap in (False, True):
            rows[(Path(path).name, overlap)] = row(segmenter, args.cycles, overlap, args.realtime)

    def ms(v: float | None) -> str:
        return "-" if v is None else f"{v:.1f}"

    lines = [f"# Pick loop in the synthetic cell: frame -> first command, {args.threads} threads, {args.engine}", "",
             f"Command: `python benchmarks/pick_latency.py {' '.join(sys.argv[1:])}`  ",
             f"{machine_line()}; onnxruntime {ort.__version__}; synthetic cell 640x480 (seed 100, camera 0.7 m over the "
             f"table), SimRobot at {args.realtime}x real time; {args.cycles} cycles after 2 warm-up, one process. "
             "Medians in ms.", "",
             "| Model | overlap | cycles | picked | inference | grasp | frame -> plan (p95) | frame -> first command "
             "| command - inference | frame -> frame | arm waits | motion per cycle (s, simulated) |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for (name, overlap), r in rows.items():
        above = None if r["command"] is None else r["command"] - r["inference"]
        lines.append(f"| {name} | {'yes' if overlap else 'no'} | {r['cycles']} | {r['picked']} | {r['inference']:.1f} | "
                     f"{r['grasp']:.1f} | {ms(r['plan'])} ({r['plan_p95']:.1f}) | {ms(r['command'])} | {ms(above)} | "
                     f"{ms(r['frame'])} | {ms(r['wait'])} | {ms(r['motion'])} |")
    lines += ["", "frame -> plan: perception, target choice, planning and the envelope check of every pose; frame -> "
              "first command adds issuing the first moveL (with overlap, the frame was read while the arm was still "
              "placing, so it also holds the rest of that motion). Arm waits: from the previous cycle's last command "
              "done to this cycle's first command sent, the time the arm stands still for the camera and the "
              "computer. Target: frame -> first command at most 5 ms above inference (without overlap)."]
    emit("\n".join(lines) + "\n", args)


if __name__ == "__main__":
    main()
