"""`edgepick demo` / `make demo`: the main job end to end on an embedded default.

Synthetic scenes -> a small CPU training run -> evaluation on the test split. Later stages
(int8 passes, the runtime, the sim robot, the bench table) join as they land.
"""

from __future__ import annotations

import json
import shutil
import time
from pathlib import Path

import click


def _step(title: str) -> None:
    click.echo(click.style(f"\n== {title}", bold=True), err=True)


def run_demo(workdir: Path, scenes: int = 204, epochs: int = 12, size: tuple[int, int] = (192, 256)) -> dict:
    """Run the demo in WORKDIR (recreated) and print a summary; returns it."""
    from edgepick.data.preview import contact_sheet
    from edgepick.data.synth import SynthConfig, synthesize
    from edgepick.evaluation import evaluate
    from edgepick.train.loop import TrainConfig, train

    if workdir.exists():
        shutil.rmtree(workdir)
    workdir.mkdir(parents=True)
    t0 = time.perf_counter()
    _step(f"1/3 synthesize {scenes} RGB-D scenes (640x480)")
    synth = synthesize(workdir / "data", SynthConfig(scenes=scenes, seed=0))
    click.echo(f"{synth['scenes']} scenes in {synth['seconds']} s ({synth['scenes_per_s']} scenes/s), "
               f"splits {synth['splits']}", err=True)
    contact_sheet(workdir / "data", workdir / "preview.png", count=9)
    _step(f"2/3 train DeepLabV3-MobileNetV3 on CPU, {epochs} epochs at {size[0]}x{size[1]}")
    run = train(TrainConfig(data=str(workdir / "data"), out=str(workdir / "run"), epochs=epochs, batch_size=8,
                            size=size, device="cpu", keep_epochs=[max(1, epochs - 1)]))
    _step("3/3 evaluate the best checkpoint on the test split")
    test = evaluate(workdir / "run", workdir / "data", "test")
    summary = {
        "data": str(workdir / "data"), "preview": str(workdir / "preview.png"), "run": run["out"],
        "train_time_s": run["train_time_s"], "best_val_miou": run["best_miou"],
        "test": {"pixel_acc": test["pixel_acc"], "miou": test["miou"],
                 "per_class_iou": {c: v["iou"] for c, v in test["per_class"].items()}},
        "total_s": round(time.perf_counter() - t0, 1),
    }
    (workdir / "summary.json").write_text(json.dumps(summary, indent=1))
    click.echo(json.dumps(summary, indent=1))
    return summary
