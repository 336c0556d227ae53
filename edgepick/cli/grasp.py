"""`edgepick grasp`: grasp records from a label image or a model run on one frame."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import TYPE_CHECKING

import click

from edgepick.cli.options import choice
from edgepick.errors import ConfigError
from edgepick.files import atomic_path, check_output
from edgepick.runtime.engine import Engine

if TYPE_CHECKING:
    import numpy as np


@click.command()
@click.option("--mask", "mask_path", default=None, type=click.Path(dir_okay=False),
              help="Mask mode: label image (uint8 class ids), e.g. DATA/<split>/mask/<id>.png.")
@click.option("--model", "model_path", default=None, type=click.Path(dir_okay=False),
              help="Model mode: an edgepick ONNX (docs/contracts.md#onnx-model) run on --rgb.")
@click.option("--rgb", "rgb_path", default=None, type=click.Path(dir_okay=False), help="Colour image for --model.")
@click.option("--depth", "depth_path", required=True, type=click.Path(dir_okay=False), help="uint16 depth PNG.")
@click.option("--intrinsics", required=True, type=click.Path(dir_okay=False),
              help="intrinsics.json (docs/contracts.md#intrinsics-and-calibration).")
@click.option("--calib", default=None, type=click.Path(dir_okay=False), help="calib.json: adds pose_robot.")
@click.option("--classes", default=None,
              help="Mask mode: class names by id, comma-separated [default: the synthetic set's five]. "
                   "Model mode takes them from the model.")
@click.option("--threads", default=2, show_default=True, help="Inference threads (model mode).")
@click.option("--engine", default=Engine.ONNXRUNTIME.value, show_default=True, type=choice(Engine),
              help="Model mode: inference engine (openvino: the [peers] extra; auto: the faster one here, measured "
                   "once per model and cached in ~/.cache/edgepick).")
@click.option("--overlay", default=None, type=click.Path(dir_okay=False), help="Write a PNG with centroids, axes, fingers.")
@click.option("--profile", is_flag=True,
              help="Print per-stage milliseconds (pre, inference, post, grasp) and the grasp step's sub-steps to stderr: "
                   "median of 5 runs after one warm-up.")
def grasp(mask_path: str | None, model_path: str | None, rgb_path: str | None, depth_path: str, intrinsics: str,
          calib: str | None, classes: str | None, threads: int, engine: Engine, overlay: str | None,
          profile: bool) -> None:
    """Grasp records (JSON list, docs/contracts.md#grasp-record) for every object in a label image or a model's output.

    Median 3x3 and dilate 5x5 per class, one record per region: centroid and major-axis
    angle from image moments, depth from the object's own valid pixels, 3D point, and with
    --calib the robot pose (tool z down, fingers across the object). Give either --mask, or
    --model with --rgb.
    """
    import cv2
    import numpy as np

    from edgepick.frames import Frame, read_depth, read_rgb
    from edgepick.geometry import Intrinsics
    from edgepick.runtime.calibration import Calibration
    from edgepick.runtime.grasp import DEFAULT_CLASSES, Laps, draw_overlay, grasp_records
    from edgepick.runtime.pipeline import Pipeline, median_ms

    if bool(mask_path) == bool(model_path):
        raise ConfigError("give either --mask (mask mode) or --model with --rgb (model mode)")
    if model_path and not rgb_path:
        raise ConfigError("--model needs --rgb, the colour image to segment")
    if mask_path and rgb_path:
        raise ConfigError("--rgb goes with --model; mask mode reads the labels from --mask")
    if overlay is not None:
        check_output(overlay, "--overlay", suffixes=(".png", ".jpg", ".jpeg"),
                     inputs=(mask_path, model_path, rgb_path, depth_path, intrinsics, calib))
    if classes is not None and model_path:
        raise ConfigError("--classes is for mask mode; a model carries its own class names")
    names = [c.strip() for c in classes.split(",")] if classes is not None else list(DEFAULT_CLASSES)
    if len(names) < 2 or not all(names):
        raise ConfigError(f"--classes {classes!r}: give every class id a name, background first, e.g. "
                          f"{','.join(DEFAULT_CLASSES)}")
    twice = next((n for n in names if names.count(n) > 1), None)
    if twice is not None:  # two ids of one name: which object a record names would be a guess
        raise ConfigError(f"--classes {classes!r}: names {twice!r} twice; each class id needs its own name")
    depth = read_depth(depth_path)
    intr = Intrinsics.load(intrinsics)
    cal = Calibration.load(calib) if calib else None
    if model_path and rgb_path:  # model mode (--model comes with --rgb: checked above)
        from edgepick.runtime.session import Segmenter

        frame = Frame(read_rgb(rgb_path), depth, intr, Path(rgb_path).stem)
        pipeline = Pipeline(Segmenter(model_path, threads=threads, engine=engine), cal, profile=profile)
        runs = [pipeline(frame) for _ in range(6 if profile else 1)]
        labels, records, timings = runs[-1].labels, runs[-1].records, [r.ms for r in runs[1:]]
        steps = [r.grasp_ms for r in runs[1:]]
        picture = frame.rgb
    else:
        assert mask_path is not None  # mask mode: --mask is given (checked above)
        labels = _read_labels(mask_path)
        unnamed = sorted({int(v) for v in np.unique(labels) if len(names) <= v < 255})  # 255: ignored pixels
        if unnamed:
            click.echo(f"edgepick: warning: label ids {', '.join(map(str, unnamed))} of {mask_path} have no name "
                       f"in the {len(names)} classes; those regions are skipped", err=True)
        timings, steps = [], []
        for _ in range(6 if profile else 1):
            laps = Laps() if profile else None
            t0 = time.perf_counter()
            records = grasp_records(labels, depth, intr, names, cal, laps=laps)
            timings.append({"grasp": 1000 * (time.perf_counter() - t0)})
            steps.append(laps.ms if laps else {})
        timings, steps = timings[1:], steps[1:]
        picture = labels
    if overlay is not None:
        with atomic_path(overlay) as tmp:
            if not cv2.imwrite(str(tmp), draw_overlay(picture, records)):
                raise ConfigError(f"cannot write overlay {overlay}")
    if profile:
        med = median_ms(timings)
        click.echo(" | ".join(f"{k} {v:.2f} ms" for k, v in med.items()), err=True)
        click.echo("grasp sub-steps: " + " | ".join(f"{k} {np.median([s[k] for s in steps]):.2f} ms" for k in Laps.STEPS),
                   err=True)
    click.echo(json.dumps([r.to_dict() for r in records], indent=1))



def _read_labels(mask_path: str) -> np.ndarray:
    """The label image of --mask: one uint8 class id per pixel, refused in one line otherwise."""
    import cv2

    labels = cv2.imread(mask_path, cv2.IMREAD_UNCHANGED)
    if labels is None or labels.ndim != 2 or labels.dtype != "uint8":
        raise ConfigError(f"cannot read {mask_path} as a single-channel uint8 label image")
    return labels
