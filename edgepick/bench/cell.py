"""`edgepick bench --cell N`: thesis Table 5.6 with its grasp success column, measured in the
closed loop. Each model runs N executions of the whole pick cycle in the synthetic cell (camera
0.7 m above the table, SimRobot, the same N seeded scenes for every model), judged per cycle by
robot/verdict.py; a first row runs the same cycles on the scenes' true labels, the grasp step's
own ceiling without a model."""

from __future__ import annotations

import csv
import json
from dataclasses import asdict, dataclass, field
from pathlib import Path

import cv2
import numpy as np
import onnxruntime as ort

from edgepick.bench.machine import machine_line
from edgepick.bench.measure import mode_label
from edgepick.bench.report import markdown
from edgepick.data.render import CLASSES
from edgepick.robot.grippers import DigitalGripper
from edgepick.robot.loop import run_cycles
from edgepick.robot.pick import CommandLog, PickConfig
from edgepick.robot.verdict import summarize
from edgepick.runtime.pipeline import Pipeline
from edgepick.runtime.session import Segmenter
from edgepick.sim.camera import SynthCamera
from edgepick.sim.oracle import TruthPipeline
from edgepick.sim.robot import SimRobot

HEADER = ["Mode", "Pipeline mean [std] (ms)", "p50 (ms)", "p95 (ms)", "Size (MB)", "Grasp success (%)",
          "of reachable (%)", "Failures"]
MOUNT_M = 0.7


@dataclass
class CellRow:
    mode: str
    model: str
    cycles: int
    mean_ms: float
    std_ms: float
    p50_ms: float
    p95_ms: float
    size_mb: float | None
    success: int
    success_rate: float
    success_rate_reachable: float | None
    failures: dict[str, int] = field(default_factory=dict)


def cell_row(mode: str, model: str, pipeline: Pipeline, cycles: int, seed: int, size_mb: float | None) -> CellRow:
    """CYCLES executions of the pick loop with PIPELINE on the cell's scenes of SEED."""
    camera = SynthCamera(640, 480, seed=seed, mount_height_m=MOUNT_M)
    truth = camera.calibration()
    robot = SimRobot()
    with camera, robot:
        results = run_cycles(camera, pipeline, robot, DigitalGripper(robot, 0), PickConfig(), cycles,
                             CommandLog(None), echo=lambda line: None, truth_cal=truth)
    times = np.array([r["plan_ms"] for r in results])  # frame -> labels -> records -> the checked plan
    summary = summarize(results)
    return CellRow(mode, model, len(results), round(float(times.mean()), 2), round(float(times.std()), 2),
                   round(float(np.median(times)), 2), round(float(np.percentile(times, 95)), 2), size_mb,
                   summary["success"], summary["success_rate"], summary["success_rate_reachable"], summary["failures"])


def run_cell(models: list[str | Path], cycles: int, out_dir: str | Path, threads: int = 2, seed: int = 0,
             engine: str = "onnxruntime", progress=print) -> dict:
    """The true-label row, then each model's, over the same CYCLES scenes; writes cell.md/.csv/.json
    and success-latency.png in OUT_DIR."""
    camera = SynthCamera(640, 480, seed=seed, mount_height_m=MOUNT_M)
    progress(f"cell: true labels, {cycles} cycles ...")
    rows = [cell_row("true labels", "-", TruthPipeline(list(CLASSES), camera.calibration()), cycles, seed, None)]
    for m in models:
        seg = Segmenter(m, threads=threads, engine=engine)
        progress(f"cell: {Path(m).name}, {cycles} cycles ...")
        rows.append(cell_row(mode_label(seg.info.metadata), str(m), Pipeline(seg, camera.calibration()), cycles, seed,
                             round(Path(m).stat().st_size / 1e6, 3)))
    modes = [r.mode for r in rows]
    for r in rows:  # two models of one mode (the demo's hybrid and the reference one): name the files
        if modes.count(r.mode) > 1:
            r.mode = f"{r.mode} ({Path(r.model).stem})"
    context = {"title": f"Table 5.6 in the synthetic cell: {cycles} executions per model",
               "machine": machine_line().removeprefix("Machine: "), "onnxruntime": ort.__version__, "opencv": cv2.__version__,
               "threads": threads, "engine": engine, "scenes": f"SynthCamera seed {seed}, 640x480, {MOUNT_M} m above the table",
               "criterion": "docs/contracts.md#grasp-success"}
    return {"rows": [asdict(r) for r in rows], "reports": write_cell_reports(rows, out_dir, context)}


def table(rows: list[CellRow]) -> list[list[str]]:
    def pct(v: float | None) -> str:
        return "-" if v is None else f"{100 * v:.0f}"

    return [[r.mode, f"{r.mean_ms:.1f} [{r.std_ms:.1f}]", f"{r.p50_ms:.1f}", f"{r.p95_ms:.1f}",
             "-" if r.size_mb is None else f"{r.size_mb:.2f}", f"{pct(r.success_rate)} ({r.success}/{r.cycles})",
             pct(r.success_rate_reachable), ", ".join(f"{k} {v}" for k, v in r.failures.items()) or "-"] for r in rows]


def write_cell_reports(rows: list[CellRow], out_dir: str | Path, context: dict) -> dict[str, str]:
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {"md": out / "cell.md", "csv": out / "cell.csv", "json": out / "cell.json", "png": out / "success-latency.png"}
    md = [f"# {context['title']}", ""] + [f"- {k}: {v}" for k, v in context.items() if k != "title"]
    paths["md"].write_text("\n".join(md + ["", markdown(HEADER, table(rows))]) + "\n")
    with open(paths["csv"], "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(HEADER)
        writer.writerows(table(rows))
    paths["json"].write_text(json.dumps({"context": context, "rows": [asdict(r) for r in rows]}, indent=1))
    _plot(rows, paths["png"])
    return {k: str(v) for k, v in paths.items()}


def _plot(rows: list[CellRow], path: Path, w: int = 800, h: int = 420) -> None:
    """Grasp success (%) per row as bars, each labelled with its pipeline p50."""
    img = np.full((h, w, 3), 255, np.uint8)
    left, bottom, top = 60, h - 70, 30
    bar = max(20, (w - left - 30) // max(1, len(rows)) - 20)
    black = (0, 0, 0)
    for pct in range(0, 101, 20):
        y = int(bottom - pct / 100 * (bottom - top))
        cv2.line(img, (left, y), (w - 20, y), (210, 210, 210), 1)
        cv2.putText(img, str(pct), (20, y + 5), cv2.FONT_HERSHEY_SIMPLEX, 0.45, black, 1)
    for i, r in enumerate(rows):
        x = left + 15 + i * (bar + 20)
        y = int(bottom - r.success_rate * (bottom - top))
        cv2.rectangle(img, (x, y), (x + bar, bottom), (200, 120, 40) if i else (120, 120, 120), -1)
        cv2.putText(img, r.mode[:14], (x, bottom + 20), cv2.FONT_HERSHEY_SIMPLEX, 0.42, black, 1, cv2.LINE_AA)
        cv2.putText(img, f"{r.p50_ms:.0f} ms", (x, bottom + 40), cv2.FONT_HERSHEY_SIMPLEX, 0.42, black, 1, cv2.LINE_AA)
    cv2.putText(img, "grasp success (%)", (10, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, black, 1, cv2.LINE_AA)
    if not cv2.imwrite(str(path), img):
        raise OSError(f"could not write {path}")
