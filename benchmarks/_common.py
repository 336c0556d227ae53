"""Helpers shared by the benchmark scripts (run as `python benchmarks/NAME.py`).

Each script prints a Markdown report; `--out FILE` also writes it there, `--save` writes it to
benchmarks/results/<study>/<yyyy-mm-dd>-<machine>.md, the study named after the script.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from edgepick.machine import machine_line, results_file  # noqa: E402,F401 - machine_line for the scripts
from edgepick.runtime.session import interleaved_times  # noqa: E402,F401 - one timing rule for every script

RESULTS = Path(__file__).resolve().parent / "results"


def untrained_checkpoint(path: Path, size, classes: list[str], variant: str = "standard") -> Path:
    """A seeded, untrained default model (DeepLabV3-MobileNetV3) as a checkpoint: latency does
    not depend on the weights, so speed benchmarks need no training run. SIZE: the model input, a Size."""
    import torch

    from edgepick.models import ModelConfig, build_model
    from edgepick.train.checkpoint import Checkpoint

    torch.manual_seed(0)
    cfg = ModelConfig(num_classes=len(classes), variant=variant)
    Checkpoint(model_config=cfg, classes=tuple(classes), input_size=size, model=build_model(cfg).state_dict()).save(path)
    return path


def study_name() -> str:
    """The running script's study: benchmarks/quant_speed.py -> quant-speed."""
    return Path(sys.argv[0]).stem.replace("_", "-")


def add_output(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--out", default=None, help="also write the Markdown report to this file")
    ap.add_argument("--save", action="store_true",
                    help=f"also write it to benchmarks/results/{study_name()}/<yyyy-mm-dd>-<machine>.md")


def emit(report: str, args: argparse.Namespace, suffix: str = "") -> None:
    """Print a Markdown report, and write it where --out / --save say (--save: SUFFIX after the
    machine in the file name, for a study with one file per model)."""
    print(report)
    targets = [Path(args.out)] if args.out else []
    if args.save:
        from edgepick.machine import machine_slug

        targets.append(results_file(RESULTS, study_name(), f"{machine_slug()}-{suffix}" if suffix else None))
    for path in targets:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(report)
        print(f"written to {path}", file=sys.stderr)


def object_agreement(ours, reference) -> float:
    """The share of object pixels (those either labels as something other than class 0) on which the
    label maps OURS equal REFERENCE's: the fidelity measure that chance cannot raise."""
    same = total = 0
    for a, b in zip(ours, reference):
        objects = (a > 0) | (b > 0)
        same += int(((a == b) & objects).sum())
        total += int(objects.sum())
    return same / max(total, 1)


