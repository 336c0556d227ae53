"""`edgepick demo` / `make demo`: the main job end to end on an embedded default.

The demo is the quick Table 5.5 / 5.6 (edgepick/bench/table55.py, its QUICK setting) shown step by
step, plus what the table does not do: synthetic scenes -> a small CPU float run -> evaluation on
the test split -> the int8 passes from that one run (fp32 export, static PTQ, QaT from scratch,
hybrid-QaT 1/5/10%) -> every ONNX file evaluated with the runtime -> pick cycles on the simulated
robot with the shipped reference int8 model (edgepick/reference: a model trained far longer than
the demo can; the demo's own models are too weak to pick), each cycle judged against the scenes'
truth -> the bench: Table 5.5 / 5.6 of the demo's models and Table 5.6's grasp success column for
them and the reference model. One float run serves every pass, as in the table: nothing is
trained twice.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

import click

from edgepick.files import output_dir

if TYPE_CHECKING:
    from edgepick.bench.table55 import Setting

CELL_CYCLES = 20  # pick cycles per model for the demo's grasp success column (bench --cell)
PICK_CYCLES = 10  # the demo's pick step
COMMAND = "edgepick demo"


class _Steps:
    """The demo's numbered steps on stderr: each says how long it took when the next one begins."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}  # step number ("1/7") -> seconds
        self._open: tuple[str, float] | None = None

    def start(self, title: str) -> None:
        self.close()
        click.echo(click.style(f"\n== {title}", bold=True), err=True)
        self._open = (title.split(" ", 1)[0], time.perf_counter())

    def close(self) -> None:
        if self._open is not None:
            number, t0 = self._open
            self.seconds[number] = round(time.perf_counter() - t0, 1)
            click.echo(f"-- step {number} took {self.seconds[number]:.0f} s", err=True)
            self._open = None


_steps = _Steps()


def _step(title: str) -> None:
    _steps.start(title)


def demo_setting(scenes: int = 48, epochs: int = 100) -> Setting:
    """The demo's scale: the quick table's setting with SCENES split 2:1:1 into train/val/test and
    an epoch budget of EPOCHS (hybrid-QaT trains its last 1/5/10%)."""
    from edgepick.bench.table55 import QUICK

    train, val = scenes // 2, scenes // 4
    return replace(QUICK, name="demo", splits=(train, val, scenes - train - val), epochs=epochs)


def run_demo(workdir: Path, scenes: int = 48, epochs: int = 100) -> dict:
    """Run the demo in WORKDIR and print a summary; returns it. WORKDIR must be new, empty or an
    earlier demo's (emptied first); an interrupted demo leaves it empty (files.output_dir)."""
    with output_dir(workdir, "demo", fresh=True):
        return _run_demo(workdir, demo_setting(scenes, epochs))


def _run_demo(workdir: Path, setting: Setting) -> dict:
    from edgepick.bench.table55 import make_table55
    from edgepick.data.preview import contact_sheet
    from edgepick.evaluation import evaluate
    from edgepick.reference import reference_model
    from edgepick.train.run import Run

    def phases(*only: str) -> dict | None:  # the table's phases, in the demo's folder
        return make_table55(workdir, setting, "cpu", COMMAND, echo=lambda line: click.echo(line, err=True),
                            only=set(only) if only else None)

    t0 = time.perf_counter()
    _steps.seconds.clear()
    _step(f"1/7 synthesize {sum(setting.splits)} RGB-D scenes (640x480; train/val/test {list(setting.splits)})")
    phases("synth")
    contact_sheet(workdir / "data", workdir / "preview.png", count=9)
    _step(f"2/7 train DeepLabV3-MobileNetV3 on CPU, {setting.epochs} epochs at {setting.size} "
          "(keeping the epochs hybrid-QaT starts from)")
    phases("float")
    run = json.loads(Run(workdir / "float").metrics.read_text())
    _step("3/7 evaluate the best checkpoint on the test split")
    test = evaluate(workdir / "float", workdir / "data", "test")
    _step("4/7 the int8 passes from that run: fp32 export, static PTQ, QaT from scratch, hybrid-QaT 1/5/10% "
          "(onnxruntime QDQ)")
    phases("fp32", "static", "qat", "hybrid")
    onnx = evaluate_demo(workdir)
    reference = reference_model()
    if reference is None:
        click.echo("no reference model in this install (edgepick/reference/): picking with the demo's own model",
                   err=True)
    picks = pick_demo(workdir, reference or Path(onnx["hybrid-QaT 10%"]["file"]))
    bench = bench_demo(workdir, phases, [Path(f["file"]) for f in onnx.values()], reference)
    _steps.close()
    summary = {
        "data": str(workdir / "data"), "preview": str(workdir / "preview.png"), "run": str(workdir / "float"),
        "train_time_s": run.get("train_time_s"), "best_val_miou": run.get("best_miou"),
        "test": {"pixel_acc": test["pixel_acc"], "miou": test["miou"],
                 "per_class_iou": {c: v["iou"] for c, v in test["per_class"].items()}},
        "onnx": onnx, "picks": picks, **bench, "step_s": dict(_steps.seconds),
        "total_s": round(time.perf_counter() - t0, 1),
    }
    (workdir / "summary.json").write_text(json.dumps(summary, indent=1))
    click.echo(json.dumps(summary, indent=1))
    click.echo(Path(bench["table55"]).read_text())
    return summary


def evaluate_demo(workdir: Path) -> dict:
    """Every ONNX file of the passes evaluated with the runtime on the test split, by its phase's
    name: size, mIoU and (int8) the label agreement of onnxruntime with torch's simulation that the
    pass measured."""
    from edgepick.bench.table55 import model_files
    from edgepick.evaluation import evaluate

    _step("5/7 evaluate the ONNX files with the runtime (onnxruntime, CPU) on the test split")
    files = model_files(workdir)
    agreement = json.loads((workdir / "phases.json").read_text()).get("agreement", {})
    fp32_size = files["fp32 export"].stat().st_size
    out = {}
    for name, f in files.items():
        res = evaluate(f, workdir / "data", "test", progress=False)
        size = f.stat().st_size
        out[name] = {"file": str(f), "size_mb": round(size / 1e6, 2), "smaller_than_fp32": round(fp32_size / size, 2),
                     "agreement_vs_torch": agreement.get(name), "test_miou": res["miou"],
                     "test_pixel_acc": res["pixel_acc"]}
        a = out[name]["agreement_vs_torch"]
        click.echo(f"{name:16s} {out[name]['size_mb']:6.2f} MB ({out[name]['smaller_than_fp32']}x smaller)  "
                   f"test mIoU {res['miou']:.3f}  onnxruntime-vs-torch agreement {'-' if a is None else a}", err=True)
    return out


def pick_demo(workdir: Path, model: Path, cycles: int = PICK_CYCLES) -> dict:
    """Pick cycles on SimRobot: a synthetic camera over a calibrated cell, the int8 model, a magnet."""
    from edgepick.robot.grippers import DigitalGripper
    from edgepick.robot.loop import Cell, cycles_summary, run_cycles
    from edgepick.robot.pick import CommandLog, PickConfig
    from edgepick.runtime.pipeline import Pipeline
    from edgepick.runtime.session import Segmenter
    from edgepick.sim.camera import SynthCamera
    from edgepick.sim.robot import SimRobot

    _step(f"6/7 pick and place on the simulated UR3: {cycles} synthetic scenes, {model.name}")
    camera = SynthCamera(seed=100, mount_height_m=0.7)
    truth = camera.calibration()
    pipeline = Pipeline(Segmenter(model, threads=2), truth)
    log = CommandLog(workdir / "picks.jsonl")
    try:
        with camera, SimRobot() as robot:
            results = run_cycles(Cell(camera, pipeline, robot, DigitalGripper(robot, 0), log, truth), cfg=PickConfig(),
                                 cycles=cycles, overlay_dir=workdir / "picks", echo=lambda line: click.echo(line, err=True))
    finally:
        log.close()
    return {"model": str(model), **cycles_summary(results), "overlays": str(workdir / "picks"),
            "log": str(workdir / "picks.jsonl")}


def bench_demo(workdir: Path, phases: Callable[..., dict | None], models: list[Path],
               reference: Path | None) -> dict:
    """The bench: thesis Table 5.5 / 5.6 of the demo's models (the table's own bench phase), then
    Table 5.6's grasp success column in the synthetic cell for them and the REFERENCE model."""
    from edgepick.bench.cell import run_cell

    _step(f"7/7 bench: thesis Table 5.5 / 5.6 for the demo's models (2 threads, same images, one process), and "
          f"Table 5.6's grasp success over {CELL_CYCLES} cycles in the synthetic cell")
    table = phases()
    assert table is not None, "make_table55 with every phase done makes the table"
    out = workdir / "table55-quick.md"
    out.write_text(table["markdown"])
    cell = run_cell(models + ([reference] if reference else []), CELL_CYCLES, workdir / "bench",
                    progress=lambda line: None)
    click.echo(Path(cell["reports"]["md"]).read_text(), err=True)  # Table 5.6 with grasp success
    return {"table55": str(out), "cell": cell["reports"]["md"]}
