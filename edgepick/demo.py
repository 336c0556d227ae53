"""`edgepick demo` / `make demo`: the main job end to end on an embedded default.

Synthetic scenes -> a small CPU training run -> evaluation on the test split -> fp32 export,
static int8 and hybrid-QaT int8 ONNX files, evaluated with the runtime -> pick cycles on the
simulated robot from synthetic scenes with the shipped reference int8 model (edgepick/reference:
a model trained far longer than the demo can; the demo's own 12-epoch model is too weak to pick),
each cycle judged against the scenes' truth. Then the bench table (thesis Table 5.5 / 5.6 shape)
of the demo's three models, Table 5.6's grasp success column for them and the reference model,
and it ends with the quick Table 5.5 / 5.6 (edgepick/bench/table55.py: its own small float run,
static, QaT from scratch and hybrid-QaT 1/5/10%).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import click

from edgepick.files import output_dir
from edgepick.geometry import Size

CELL_CYCLES = 20  # pick cycles per model for the demo's grasp success column (bench --cell)
PICK_CYCLES = 10  # the demo's pick step


class _Steps:
    """The demo's numbered steps on stderr: each says how long it took when the next one begins."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}  # step number ("1/8") -> seconds
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


def run_demo(workdir: Path, scenes: int = 204, epochs: int = 12, size: Size = Size(192, 144)) -> dict:
    """Run the demo in WORKDIR and print a summary; returns it. WORKDIR must be new, empty or an
    earlier demo's (emptied first); an interrupted demo leaves it empty (files.output_dir)."""
    with output_dir(workdir, "demo", fresh=True):
        return _run_demo(workdir, scenes, epochs, size)


def _run_demo(workdir: Path, scenes: int, epochs: int, size: Size) -> dict:
    from edgepick.data.preview import contact_sheet
    from edgepick.data.synth import SynthConfig, synthesize
    from edgepick.evaluation import evaluate
    from edgepick.reference import reference_model
    from edgepick.train.config import Device
    from edgepick.train.loop import TrainConfig, train

    t0 = time.perf_counter()
    _steps.seconds.clear()
    _step(f"1/8 synthesize {scenes} RGB-D scenes (640x480)")
    synth = synthesize(workdir / "data", SynthConfig(scenes=scenes, seed=0))
    click.echo(f"{synth['scenes']} scenes in {synth['seconds']} s ({synth['scenes_per_s']} scenes/s), "
               f"splits {synth['splits']}", err=True)
    contact_sheet(workdir / "data", workdir / "preview.png", count=9)
    _step(f"2/8 train DeepLabV3-MobileNetV3 on CPU, {epochs} epochs at {size}")
    run = train(TrainConfig(data=str(workdir / "data"), out=str(workdir / "run"), epochs=epochs, batch_size=8,
                            size=size, device=Device.CPU, keep_epochs=(max(1, epochs - 1),)))
    _step("3/8 evaluate the best checkpoint on the test split")
    test = evaluate(workdir / "run", workdir / "data", "test")
    int8 = quantize_demo(workdir, epochs)
    reference = reference_model()
    if reference is None:
        click.echo("no reference model in this install (edgepick/reference/): picking with the demo's own model",
                   err=True)
    picks = pick_demo(workdir, reference or Path(int8["hybrid"]["file"]))
    table = bench_demo(workdir, [Path(int8[name]["file"]) for name in ("fp32", "static", "hybrid")], reference)
    quick = quick_table_demo(workdir)
    _steps.close()
    summary = {
        "data": str(workdir / "data"), "preview": str(workdir / "preview.png"), "run": run.out,
        "train_time_s": run.train_time_s, "best_val_miou": run.best_miou,
        "test": {"pixel_acc": test["pixel_acc"], "miou": test["miou"],
                 "per_class_iou": {c: v["iou"] for c, v in test["per_class"].items()}},
        "onnx": int8, "picks": picks, "bench": table, "quick_table55": quick, "step_s": dict(_steps.seconds),
        "total_s": round(time.perf_counter() - t0, 1),
    }
    (workdir / "summary.json").write_text(json.dumps(summary, indent=1))
    click.echo(json.dumps(summary, indent=1))
    click.echo(Path(quick).read_text())
    return summary


def quantize_demo(workdir: Path, epochs: int) -> dict:
    """fp32 export, static int8 and hybrid-QaT int8 (last epoch with QaT); runtime eval of each."""
    from edgepick.evaluation import evaluate
    from edgepick.export.onnx_export import ExportResult, export_checkpoint
    from edgepick.quant import PassResult, agreement_images, folder_images, quantize_hybrid, quantize_static, run_images
    from edgepick.train.config import Device

    _step("4/8 export fp32, quantize static int8 and hybrid-QaT int8 (onnxruntime QDQ)")
    models = workdir / "models"
    files: dict[str, ExportResult | PassResult] = {
             "fp32": export_checkpoint(workdir / "run", models / "fp32.onnx"),
             "static": quantize_static(workdir / "run", folder_images(workdir / "data", "train", 32),
                                       models / "static.onnx", check_images=agreement_images(workdir / "data")),
             "hybrid": quantize_hybrid(workdir / "run", workdir / "data", models / "hybrid.onnx", 1 / epochs,
                                       run_images(workdir / "run", workdir / "data"), qat_run=workdir / "hybrid.run",
                                       device=Device.CPU)}
    _step("5/8 evaluate the ONNX files with the runtime (onnxruntime, CPU) on the test split")
    fp32_size = files["fp32"].size_bytes
    out = {}
    for name, f in files.items():
        res = evaluate(f.out, workdir / "data", "test", progress=False)
        out[name] = {"file": f.out, "size_mb": round(f.size_bytes / 1e6, 2),
                     "smaller_than_fp32": round(fp32_size / f.size_bytes, 2),
                     "agreement_vs_torch": getattr(f, "agreement_vs_torch", None), "test_miou": res["miou"],
                     "test_pixel_acc": res["pixel_acc"]}
        agreement = out[name]["agreement_vs_torch"]
        click.echo(f"{name:7s} {out[name]['size_mb']:6.2f} MB ({out[name]['smaller_than_fp32']}x smaller)  "
                   f"test mIoU {res['miou']:.3f}  onnxruntime-vs-torch agreement {'-' if agreement is None else agreement}",
                   err=True)
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

    _step(f"6/8 pick and place on the simulated UR3: {cycles} synthetic scenes, {model.name}")
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


def bench_demo(workdir: Path, models: list[Path], reference: Path | None) -> str:
    """The quick table: Table 5.5 / 5.6 of the demo's fp32, static and hybrid-QaT models; the
    grasp success column for them and the REFERENCE model."""
    from edgepick.bench.measure import BenchConfig
    from edgepick.bench.run import run_bench

    _step(f"7/8 bench: thesis Table 5.5 / 5.6 for the demo's models (2 threads, same images, one process), and "
          f"Table 5.6's grasp success over {CELL_CYCLES} cycles in the synthetic cell")
    result = run_bench(models, workdir / "data", workdir / "bench", BenchConfig(threads=2, runs=30),
                       title="make demo: Table 5.5 / 5.6 (CPU, 12-epoch demo model)", progress=lambda line: None)
    text = Path(result["reports"]["md"]).read_text()
    click.echo(text, err=True)
    from edgepick.bench.cell import run_cell

    cell = run_cell(models + ([reference] if reference else []), CELL_CYCLES, workdir / "bench",
                    progress=lambda line: None)
    click.echo(Path(cell["reports"]["md"]).read_text(), err=True)  # Table 5.6 with grasp success
    return result["reports"]["md"]


def quick_table_demo(workdir: Path) -> str:
    """The quick Table 5.5 / 5.6: every int8 mode from one small float run (minutes on 2 cores)."""
    from edgepick.bench.table55 import QUICK, make_table55

    _step(f"8/8 the quick Table 5.5 / 5.6: {QUICK.splits} scenes, {QUICK.epochs} epochs at "
          f"{QUICK.size}: float, static, QaT from scratch, hybrid-QaT 1/5/10%")
    table = make_table55(workdir / "table55", QUICK, "cpu", "edgepick demo (step 8)",
                         echo=lambda line: click.echo(line, err=True))
    assert table is not None, "make_table55 asked for every phase makes the table"
    out = workdir / "table55-quick.md"
    out.write_text(table["markdown"])
    return str(out)
