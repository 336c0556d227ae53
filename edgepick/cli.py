"""The `edgepick` command line: a thin click layer over the package's public functions.

Heavy modules (torch, the trainer) are imported inside the commands, so `edgepick --help`
and the runtime commands start fast and work on the torch-free base install.
A user's error (EdgepickError) prints one line on stderr and exits 2; anything else exits 1.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import click

from edgepick import __version__
from edgepick.cli_options import check_data_orientation, epoch_subset, model_size, parse_size, with_options
from edgepick.errors import ConfigError, EdgepickError


def _emit(result: dict) -> None:
    click.echo(json.dumps(result, indent=1))


@click.group(context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
@click.version_option(__version__, prog_name="edgepick")
def cli() -> None:
    """edgepick: train DeepLabV3, quantize it to int8, and run robot picking on a CPU.

    \b
    The path: data synth -> train -> eval (-> quantize -> export -> grasp/pick -> bench).
    `edgepick demo` runs the main job end to end on synthetic data.
    """


# ---------------------------------------------------------------------------- data
@cli.group()
def data() -> None:
    """Make and inspect data sets (native layout, docs/contracts.md#data-set-layout)."""


@data.command("synth")
@click.argument("out", type=click.Path(file_okay=False))
@click.option("--scenes", default=510, show_default=True, help="Total scenes, split 40:10:1 like the thesis's 4000/1000/100.")
@click.option("--splits", default=None, metavar="TRAIN,VAL,TEST", help="Explicit scene counts per split (overrides --scenes).")
@click.option("--size", default="640x480", show_default=True, help="Image size, WIDTHxHEIGHT.")
@click.option("--seed", default=0, show_default=True, help="Same seed -> identical files.")
@click.option("--workers", default=0, show_default=True, help="Parallel processes; 0 = one per core.")
def data_synth(out: str, scenes: int, splits: str | None, size: str, seed: int, workers: int) -> None:
    """Render synthetic RGB-D tabletop scenes of the thesis's four objects into OUT.

    Bearings, brake disks, plug adapters and cardboard boxes, 1-4 per scene, touching and
    occluding each other, on wood/laminate/mat/steel tables under the four lighting
    conditions of thesis Table 5.3; D415-like depth with noise and holes; grasp truth.
    """
    from edgepick.data.synth import SynthConfig, synthesize

    width, height = parse_size(size)
    split_counts = None
    if splits:
        try:
            split_counts = tuple(int(v) for v in splits.split(","))
        except ValueError:
            raise ConfigError(f"--splits must be three integers TRAIN,VAL,TEST, got {splits!r}") from None
        if len(split_counts) != 3 or min(split_counts) < 1:
            raise ConfigError("--splits needs three counts, each at least 1")
        scenes = sum(split_counts)
    if scenes < 3:
        raise ConfigError("--scenes must be at least 3 (one per split)")
    cfg = SynthConfig(scenes=scenes, width=width, height=height, seed=seed, splits=split_counts, workers=workers)
    _emit(synthesize(out, cfg))


@data.command("preview")
@click.argument("data_dir", metavar="DATA", type=click.Path())
@click.option("--out", required=True, type=click.Path(dir_okay=False), help="PNG contact sheet to write.")
@click.option("--split", default="train", show_default=True)
@click.option("--count", default=12, show_default=True, help="Scenes to draw.")
def data_preview(data_dir: str, out: str, split: str, count: int) -> None:
    """Draw a contact sheet: RGB with mask overlays and grasp truth, and the depth map."""
    from edgepick.data.preview import contact_sheet

    n = contact_sheet(data_dir, out, split=split, count=count)
    _emit({"out": out, "scenes": n})


@data.command("import")
@click.argument("fmt", metavar="FORMAT", type=click.Choice(["cityscapes", "bop", "cvat"]))
@click.argument("src", type=click.Path())
@click.argument("out", type=click.Path(file_okay=False))
@click.option("--cityscapes-classes", default="30", show_default=True, type=click.Choice(["30", "19"]),
              help="Cityscapes: all 30 benchmark classes, or the 19 train ids (the rest ignored).")
@click.option("--splits", default="0.8,0.1,0.1", show_default=True, metavar="TRAIN,VAL,TEST",
              help="BOP/CVAT: fractions for the train/val/test split (deterministic per file name).")
@click.option("--images", default=None, type=click.Path(file_okay=False), help="CVAT: colour images [default: SRC/JPEGImages].")
@click.option("--depth", default=None, type=click.Path(file_okay=False), help="CVAT: uint16 depth PNGs named like the images.")
@click.option("--intrinsics", default=None, type=click.Path(dir_okay=False), help="CVAT: intrinsics.json of the depth camera.")
@click.option("--depth-scale", default=0.001, show_default=True, help="CVAT: metres per unit of the depth PNGs.")
def data_import(fmt: str, src: str, out: str, cityscapes_classes: str, splits: str, images: str | None,
                depth: str | None, intrinsics: str | None, depth_scale: float) -> None:
    """Convert a Cityscapes, BOP (e.g. LineMOD) or CVAT 'Segmentation mask 1.1' tree into the native layout.

    \b
    cityscapes: leftImg8bit/ + gtFine/*_labelIds.png (ids 0-3, and with 19 classes every
                non-train id, become 255 = ignored); its val split feeds val and test.
    bop:        <scene>/rgb, depth, mask_visib, scene_gt.json, scene_camera.json; one class
                per object id, depth converted to millimetres, intrinsics from cam_K.
    cvat:       labelmap.txt + SegmentationClass/*.png, images and optional depth folders.
    """
    from edgepick.data.importers import ImportConfig, import_dataset

    try:
        fractions = tuple(float(v) for v in splits.split(","))
    except ValueError:
        raise ConfigError(f"--splits must be three fractions TRAIN,VAL,TEST, got {splits!r}") from None
    cfg = ImportConfig(cityscapes_classes=cityscapes_classes, split_fractions=fractions, images=images,
                       depth=depth, intrinsics=intrinsics, depth_scale_m=depth_scale)
    _emit(import_dataset(fmt, src, out, cfg))


@data.command("capture")
@click.argument("out", type=click.Path(file_okay=False))
@click.option("--camera", default="realsense", show_default=True,
              help="realsense[:SERIAL], synth[:SEED] or dir:PATH (the same sources as the runtime).")
@click.option("--count", default=10, show_default=True, help="Frames to save.")
@click.option("--interval", default=0.0, show_default=True, help="Seconds between frames (time to move objects).")
@click.option("--size", default="640x480", show_default=True, help="Camera stream size, WIDTHxHEIGHT.")
def data_capture(out: str, camera: str, count: int, interval: float, size: str) -> None:
    """Save aligned RGB + depth + intrinsics.json from a camera into OUT, for annotation (e.g. CVAT)."""
    from edgepick.data.capture import capture
    from edgepick.runtime.camera import open_camera

    width, height = parse_size(size)
    _emit(capture(open_camera(camera, width, height), out, count, interval))


# --------------------------------------------------------------------------- train
@cli.command()
@click.argument("data_dir", metavar="DATA", type=click.Path())
@click.option("--out", required=True, type=click.Path(file_okay=False), help="RUN folder for checkpoints and metrics.")
@click.option("--arch", default="mobilenetv3", show_default=True, type=click.Choice(["mobilenetv3", "resnet50", "resnet101"]))
@click.option("--variant", default="standard", show_default=True, type=click.Choice(["standard", "edge"]),
              help="edge: MobileNetV3 without SE and hardswish, 128-channel ASPP (quantization-friendly; not "
                   "torchvision-compatible).")
@click.option("--epochs", default=None, type=int, help="Epoch budget [default: 100; on --resume: the run's own].")
@click.option("--batch-size", default=8, show_default=True)
@click.option("--lr", default=1e-3, show_default=True, help="AdamW learning rate (poly decay, short warm-up).")
@click.option("--device", default="auto", show_default=True, type=click.Choice(["auto", "cpu", "cuda"]))
@click.option("--size", default="640x480", show_default=True,
              help="Model input size, WIDTHxHEIGHT (multiples of 8); images are resized to it.")
@click.option("--colorspace", default="rgb", show_default=True, type=click.Choice(["rgb", "hsv", "gray"]))
@click.option("--output-stride", default=16, show_default=True, type=click.Choice(["8", "16"]))
@click.option("--aux-loss/--no-aux-loss", default=False, show_default=True, help="FCN auxiliary head (weight 0.4).")
@click.option("--keep-epochs", default="", help="Comma-separated epochs whose checkpoints are kept (hybrid-QaT switch points).")
@click.option("--backbone-weights", default=None, type=click.Path(dir_okay=False), help="Backbone state dict to start from.")
@with_options(epoch_subset)
@click.option("--workers", default=-1, show_default=True,
              help="Data loader workers; -1 = decode once into memory (4 workers on GPU when that does not fit).")
@click.option("--seed", default=0, show_default=True)
@click.option("--resume", is_flag=True, help="Continue RUN from its last.pt (losing at most one epoch).")
def train(data_dir: str, out: str, arch: str, variant: str, epochs: int | None, batch_size: int, lr: float, device: str, size: str,
          colorspace: str, output_stride: str, aux_loss: bool, keep_epochs: str, backbone_weights: str | None,
          epoch_images: int, val_images: int, workers: int, seed: int, resume: bool) -> None:
    """Train a float DeepLabV3 on DATA (CPU, one GPU with bf16 AMP, or DDP under torchrun).

    Keeps best.pt (by validation mIoU), last.pt and epoch_NNN.pt for --keep-epochs, and
    metrics.json with per-epoch loss, pixel accuracy, mIoU, per-class IoU and timings.
    Multi-GPU: torchrun --nproc_per_node N -m edgepick train DATA --out RUN ...
    """
    from edgepick.train.loop import TrainConfig
    from edgepick.train.loop import train as run_train

    try:
        keep = sorted({int(v) for v in keep_epochs.split(",") if v.strip()})
    except ValueError:
        raise ConfigError(f"--keep-epochs must be comma-separated integers, got {keep_epochs!r}") from None
    input_hw = model_size(size)
    if not resume:
        check_data_orientation(data_dir, input_hw)
    cfg = TrainConfig(data=data_dir, out=out, arch=arch, variant=variant, epochs=epochs if epochs is not None else (0 if resume else 100),
                      batch_size=batch_size, lr=lr, size=input_hw, colorspace=colorspace,
                      output_stride=int(output_stride), aux_loss=aux_loss, device=device, keep_epochs=keep,
                      backbone_weights=backbone_weights, epoch_images=epoch_images, val_images=val_images,
                      workers=workers, seed=seed)
    result = run_train(cfg, resume=resume)
    if result is not None:
        _emit({k: v for k, v in result.items()})


@cli.command("eval")
@click.argument("model", type=click.Path())
@click.argument("data_dir", metavar="DATA", type=click.Path())
@click.option("--split", default="test", show_default=True, type=click.Choice(["train", "val", "test"]))
@click.option("--out", default=None, type=click.Path(dir_okay=False), help="Also write the JSON here.")
def eval_cmd(model: str, data_dir: str, split: str, out: str | None) -> None:
    """Pixel accuracy, per-class IoU, mIoU and confusion matrix of MODEL (checkpoint, RUN or ONNX) as JSON."""
    from edgepick.evaluation import evaluate

    result = evaluate(model, data_dir, split)
    if out:
        Path(out).write_text(json.dumps(result, indent=1))
    _emit(result)


# ----------------------------------------------------------------------- calibrate
@cli.command()
@click.argument("pairs", type=click.Path(dir_okay=False))
@click.option("--out", required=True, type=click.Path(dir_okay=False),
              help="calib.json to write (docs/contracts.md#intrinsics-and-calibration).")
def calibrate(pairs: str, out: str) -> None:
    """Fit the camera-to-robot transform (Kabsch, det = +1) from PAIRS.csv.

    PAIRS.csv has the header cam_x,cam_y,cam_z,robot_x,robot_y,robot_z (metres) and at
    least 4 rows of the same physical points seen by the camera and touched by the robot.
    Prints the per-pair residuals; refuses coincident or collinear points.
    """
    from edgepick.runtime.calibration import kabsch, read_pairs, residuals

    camera, robot = read_pairs(pairs)
    cal = kabsch(camera, robot)
    for i, err in enumerate(residuals(cal, camera, robot), start=1):
        click.echo(f"pair {i:3d}: residual {err * 1000:7.2f} mm", err=True)
    click.echo(f"RMSE {cal.rmse_m * 1000:.2f} mm over {cal.n_pairs} pairs", err=True)
    cal.save(out)
    _emit({"out": out, **cal.to_dict()})


# --------------------------------------------------------------------------- grasp
@cli.command()
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
@click.option("--engine", default="onnxruntime", show_default=True, type=click.Choice(["onnxruntime", "openvino"]),
              help="Model mode: inference engine (openvino: the [peers] extra).")
@click.option("--overlay", default=None, type=click.Path(dir_okay=False), help="Write a PNG with centroids, axes, fingers.")
@click.option("--profile", is_flag=True,
              help="Print per-stage milliseconds (pre, inference, post, grasp) to stderr: median of 5 runs after one warm-up.")
def grasp(mask_path: str | None, model_path: str | None, rgb_path: str | None, depth_path: str, intrinsics: str,
          calib: str | None, classes: str | None, threads: int, engine: str, overlay: str | None,
          profile: bool) -> None:
    """Grasp records (JSON list, docs/contracts.md#grasp-record) for every object in a label image or a model's output.

    Median 3x3 and dilate 5x5 per class, one record per region: centroid and major-axis
    angle from image moments, depth from the object's own valid pixels, 3D point, and with
    --calib the robot pose (tool z down, fingers across the object). Give either --mask, or
    --model with --rgb.
    """
    import cv2

    from edgepick.runtime.calibration import Calibration
    from edgepick.runtime.camera import Frame, read_depth, read_rgb
    from edgepick.runtime.geometry import Intrinsics
    from edgepick.runtime.grasp import DEFAULT_CLASSES, draw_overlay, grasp_records
    from edgepick.runtime.pipeline import Pipeline, median_ms

    if bool(mask_path) == bool(model_path):
        raise ConfigError("give either --mask (mask mode) or --model with --rgb (model mode)")
    if model_path and not rgb_path:
        raise ConfigError("--model needs --rgb, the colour image to segment")
    if mask_path and rgb_path:
        raise ConfigError("--rgb goes with --model; mask mode reads the labels from --mask")
    depth = read_depth(depth_path)
    intr = Intrinsics.load(intrinsics)
    cal = Calibration.load(calib) if calib else None
    if model_path:
        from edgepick.runtime.session import Segmenter

        frame = Frame(read_rgb(rgb_path), depth, intr, Path(rgb_path).stem)
        pipeline = Pipeline(Segmenter(model_path, threads=threads, engine=engine), cal)
        runs = [pipeline(frame) for _ in range(6 if profile else 1)]
        labels, records, timings = runs[-1].labels, runs[-1].records, [r.ms for r in runs[1:]]
        picture = frame.rgb
    else:
        labels = cv2.imread(mask_path, cv2.IMREAD_UNCHANGED)
        if labels is None or labels.ndim != 2 or labels.dtype != "uint8":
            raise ConfigError(f"cannot read {mask_path} as a single-channel uint8 label image")
        names = [c.strip() for c in classes.split(",")] if classes else list(DEFAULT_CLASSES)
        timings = []
        for _ in range(6 if profile else 1):
            t0 = time.perf_counter()
            records = grasp_records(labels, depth, intr, names, cal)
            timings.append({"grasp": 1000 * (time.perf_counter() - t0)})
        timings = timings[1:]
        picture = labels
    if overlay:
        if not cv2.imwrite(overlay, draw_overlay(picture, records)):
            raise ConfigError(f"cannot write overlay {overlay}")
    if profile:
        med = median_ms(timings)
        click.echo(" | ".join(f"{k} {v:.2f} ms" for k, v in med.items()), err=True)
    click.echo(json.dumps(records, indent=1))


# ---------------------------------------------------------------------------- demo
@cli.command()
@click.option("--workdir", default="demo-out", show_default=True, type=click.Path(file_okay=False))
@click.option("--scenes", default=204, show_default=True, help="Synthetic scenes to make.")
@click.option("--epochs", default=12, show_default=True, help="CPU training epochs.")
def demo(workdir: str, scenes: int, epochs: int) -> None:
    """The main job on an embedded default: synth data, train a small model on CPU, evaluate."""
    from edgepick.demo import run_demo

    run_demo(Path(workdir), scenes=scenes, epochs=epochs)


from edgepick.cli_quant import export_cmd, quantize  # noqa: E402 - click-only module, no torch
from edgepick.cli_bench import bench  # noqa: E402 - click-only module, no torch
from edgepick.cli_robot import pick  # noqa: E402 - click-only module, no torch

cli.add_command(export_cmd)
cli.add_command(quantize)
cli.add_command(pick)
cli.add_command(bench)


def main() -> None:
    """Console entry point: user errors -> one line and exit 2."""
    try:
        cli.main(standalone_mode=False)
    except EdgepickError as exc:
        click.echo(f"edgepick: error: {exc}", err=True)
        sys.exit(2)
    except click.exceptions.Abort:
        click.echo("edgepick: aborted", err=True)
        sys.exit(130)
    except click.ClickException as exc:
        exc.show()
        sys.exit(exc.exit_code)
    except KeyboardInterrupt:
        click.echo("edgepick: interrupted", err=True)
        sys.exit(130)


if __name__ == "__main__":
    main()
