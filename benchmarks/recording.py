"""What `pick --record` costs: the pick loop in the synthetic cell without and with a recording, in
alternating blocks in one process; per cycle the frame -> first command latency, the cycle time
(frame -> frame), the recorder's own time on its thread, and the file size.

    python benchmarks/recording.py [--model m.onnx] [--blocks 4] [--cycles 8] [--threads 2]
                                   [--realtime 0.25] [--out FILE.md | --save]

The recorder gets each cycle after its commands are sent and encodes and writes it on a worker
thread, so the frame -> first command latency should not move; the worker's time overlaps the
arm's motion (SimRobot spends --realtime wall seconds per simulated second of it). Rows at
--realtime 0 show the case with no motion to hide behind.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import mcap
import onnxruntime as ort

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from _common import add_output, emit, machine_line  # noqa: E402

from edgepick.reference import reference_model  # noqa: E402
from edgepick.robot.grippers import DigitalGripper  # noqa: E402
from edgepick.robot.loop import Cell, run_cycles  # noqa: E402
from edgepick.robot.pick import CommandLog, PickConfig  # noqa: E402
from edgepick.robot.recording import Recorder, pick_metadata  # noqa: E402
from edgepick.runtime.grasp_config import GraspConfig  # noqa: E402
from edgepick.runtime.pipeline import Pipeline  # noqa: E402
from edgepick.runtime.session import Segmenter  # noqa: E402
from edgepick.sim.camera import SynthCamera  # noqa: E402
from edgepick.sim.robot import SimRobot  # noqa: E402


def block(segmenter: Segmenter, seed: int, cycles: int, realtime: float, record: Path | None) -> dict:
    """CYCLES cycles of the cell from SEED, recorded to RECORD when given."""
    camera = SynthCamera(640, 480, seed=seed, mount_height_m=0.7)
    pipeline = Pipeline(segmenter, camera.calibration())
    robot = SimRobot(realtime=realtime)
    recorder = Recorder(record, pick_metadata("bench", pipeline.classes, PickConfig(), GraspConfig(), robot.envelope),
                        pipeline.calib) if record else None
    with camera, robot:
        start = time.perf_counter()
        cell = Cell(camera, pipeline, robot, DigitalGripper(robot, 0), CommandLog(None), recorder=recorder)
        results = run_cycles(cell, cfg=PickConfig(), cycles=cycles, echo=lambda line: None)
        loop_s = time.perf_counter() - start
    out = {"results": [r.to_dict() for r in results], "loop_s": loop_s}
    if recorder is not None:
        start = time.perf_counter()
        recorder.close()
        out.update(close_s=time.perf_counter() - start, busy_s=recorder.busy_s, bytes=record.stat().st_size)
    return out


def summary(blocks: list[dict]) -> dict:
    results = [r for b in blocks for r in b["results"]]
    cycles = len(results)

    def p50(key: str) -> float:
        return statistics.median(r[key] for r in results if key in r)

    row = {"cycles": cycles, "command": p50("frame_to_command_ms"), "frame": p50("frame_to_frame_ms"),
           "inference": statistics.median(r["stage_ms"]["inference"] for r in results),
           "loop_ms": 1000 * sum(b["loop_s"] for b in blocks) / cycles}
    if "busy_s" in blocks[0]:
        row.update(busy_ms=1000 * sum(b["busy_s"] for b in blocks) / cycles,
                   close_ms=1000 * statistics.median(b["close_s"] for b in blocks),
                   kb=sum(b["bytes"] for b in blocks) / cycles / 1024)
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", default=None, help="ONNX model [default: the shipped reference model]")
    ap.add_argument("--blocks", type=int, default=4, help="alternating blocks per setting [default: 4]")
    ap.add_argument("--cycles", type=int, default=8, help="cycles per block [default: 8]")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--realtime", type=float, default=0.25,
                    help="SimRobot's wall seconds per simulated second of motion [default: 0.25]")
    add_output(ap)
    args = ap.parse_args()

    segmenter = Segmenter(args.model or str(reference_model()), threads=args.threads)
    block(segmenter, 99, 2, 0.0, None)  # warm-up
    rows = {}
    with tempfile.TemporaryDirectory() as tmp:
        for realtime in (args.realtime, 0.0):
            runs: dict[bool, list[dict]] = {False: [], True: []}
            for b in range(args.blocks):
                for record in (False, True) if b % 2 == 0 else (True, False):
                    path = Path(tmp) / f"{realtime}-{b}.mcap" if record else None
                    runs[record].append(block(segmenter, 100 + b, args.cycles, realtime, path))
            rows.update({(realtime, record): summary(blocks) for record, blocks in runs.items()})

    lines = [f"# What `pick --record` costs per cycle: synthetic cell 640x480, {args.threads} threads", "",
             f"Command: `python benchmarks/recording.py {' '.join(sys.argv[1:])}`  ",
             f"{machine_line()}; onnxruntime {ort.__version__}, mcap {mcap.__version__}; model "
             f"{Path(segmenter.path).name}; {args.blocks} blocks of {args.cycles} cycles per row, recording off and on "
             "alternating, one process. Medians in ms.", "",
             "| SimRobot speed | record | cycles | inference | frame -> first command | frame -> frame | loop time per cycle "
             "| recorder thread per cycle | waiting at close | file per cycle (KiB) |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for (realtime, record), r in rows.items():
        extra = f"{r['busy_ms']:.1f} | {r['close_ms']:.1f} | {r['kb']:.0f}" if record else "- | - | -"
        lines.append(f"| {realtime}x real time | {'on' if record else 'off'} | {r['cycles']} | {r['inference']:.1f} | "
                     f"{r['command']:.1f} | {r['frame']:.1f} | {r['loop_ms']:.1f} | {extra} |")
    lines += ["", "frame -> first command: the latency recording must not touch. frame -> frame and loop time: the "
              "whole cycle, where the recorder thread's work competes for the CPU with the next frame's. Recorder "
              "thread: the time it spent encoding (JPEG colour and overlay) and writing (Zstandard chunks) per cycle; "
              "waiting at close: what it still had to write when the last cycle ended."]
    emit("\n".join(lines) + "\n", args)


if __name__ == "__main__":
    main()
