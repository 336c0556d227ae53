"""`edgepick data synth|preview|import|capture`: make and inspect data sets."""

from __future__ import annotations

import math
from typing import cast

import click

from edgepick.cli.options import choice, default_of, emit, parse_size
from edgepick.data.config import CityscapesClasses, ImportConfig, ImportFormat, Split
from edgepick.errors import ConfigError
from edgepick.files import check_output


@click.group()
def data() -> None:
    """Make and inspect data sets (native layout, docs/contracts.md#data-set-layout)."""


@data.command("synth")
@click.argument("out", type=click.Path(file_okay=False))
@click.option("--scenes", default=510, show_default=True, help="Total scenes, split 40:10:1 like the thesis's 4000/1000/100.")
@click.option("--splits", default=None, metavar="TRAIN,VAL,TEST", help="Explicit scene counts per split (overrides --scenes).")
@click.option("--size", default="640x480", show_default=True, help="Image size, WIDTHxHEIGHT.")
@click.option("--seed", default=0, show_default=True, help="Same seed -> identical files.")
@click.option("--workers", default=0, show_default=True,
              help="Parallel processes; 0 = one per core. Never more than the scenes or the cores.")
def data_synth(out: str, scenes: int, splits: str | None, size: str, seed: int, workers: int) -> None:
    """Render synthetic RGB-D tabletop scenes of the thesis's four objects into OUT.

    Bearings, brake disks, plug adapters and cardboard boxes, 1-4 per scene, touching and
    occluding each other, on wood/laminate/mat/steel tables under the four lighting
    conditions of thesis Table 5.3; D415-like depth with noise and holes; grasp truth.
    """
    from edgepick.data.synth import SynthConfig, synthesize

    check_output(out, "OUT", kind="dir")
    image_size = parse_size(size)
    split_counts: tuple[int, int, int] | None = None
    if splits:
        try:  # SynthConfig refuses any other count than three
            split_counts = cast("tuple[int, int, int]", tuple(int(v) for v in splits.split(",")))
        except ValueError:
            raise ConfigError(f"--splits must be three integers TRAIN,VAL,TEST, got {splits!r}") from None
        scenes = sum(split_counts)
    cfg = SynthConfig(scenes=scenes, width=image_size.width, height=image_size.height, seed=seed, splits=split_counts,
                      workers=workers)
    emit(synthesize(out, cfg))


@data.command("preview")
@click.argument("data_dir", metavar="DATA", type=click.Path())
@click.option("--out", required=True, type=click.Path(dir_okay=False), help="PNG contact sheet to write.")
@click.option("--split", default=Split.TRAIN.value, show_default=True, type=choice(Split))
@click.option("--count", default=12, show_default=True, help="Scenes to draw.")
def data_preview(data_dir: str, out: str, split: Split, count: int) -> None:
    """Draw a contact sheet: RGB with mask overlays and grasp truth, and the depth map."""
    from edgepick.data.preview import contact_sheet

    check_output(out, "--out", suffixes=(".png",), inputs=(data_dir,))
    if count < 1:
        raise ConfigError(f"--count {count}: draw at least 1 scene")
    n = contact_sheet(data_dir, out, split=split, count=count)
    emit({"out": out, "scenes": n})


@data.command("import")
@click.argument("fmt", metavar="FORMAT", type=choice(ImportFormat))
@click.argument("src", type=click.Path())
@click.argument("out", type=click.Path(file_okay=False))
@click.option("--cityscapes-classes", default=default_of(ImportConfig, "cityscapes_classes"), show_default=True,
              type=choice(CityscapesClasses),
              help="Cityscapes: all 30 benchmark classes, or the 19 train ids (the rest ignored).")
@click.option("--splits", default=",".join(map(str, default_of(ImportConfig, "split_fractions"))), show_default=True,
              metavar="TRAIN,VAL,TEST",
              help="BOP/CVAT: fractions for the train/val/test split (deterministic per file name).")
@click.option("--images", default=None, type=click.Path(file_okay=False), help="CVAT: colour images [default: SRC/JPEGImages].")
@click.option("--depth", default=None, type=click.Path(file_okay=False), help="CVAT: uint16 depth PNGs named like the images.")
@click.option("--intrinsics", default=None, type=click.Path(dir_okay=False), help="CVAT: intrinsics.json of the depth camera.")
@click.option("--depth-scale", default=default_of(ImportConfig, "depth_scale_m"), show_default=True,
              help="CVAT: metres per unit of the depth PNGs.")
def data_import(fmt: ImportFormat, src: str, out: str, cityscapes_classes: CityscapesClasses, splits: str, images: str | None,
                depth: str | None, intrinsics: str | None, depth_scale: float) -> None:
    """Convert a Cityscapes, BOP (e.g. LineMOD) or CVAT 'Segmentation mask 1.1' tree into the native layout.

    \b
    cityscapes: leftImg8bit/ + gtFine/*_labelIds.png (ids 0-3, and with 19 classes every
                non-train id, become 255 = ignored); its val split feeds val and test.
    bop:        <scene>/rgb, depth, mask_visib, scene_gt.json, scene_camera.json; one class
                per object id, depth converted to millimetres, intrinsics from cam_K.
    cvat:       labelmap.txt + SegmentationClass/*.png, images and optional depth folders.
    """
    from edgepick.data.importers import import_dataset

    check_output(out, "OUT", kind="dir", inputs=(src, images, depth, intrinsics))
    try:
        fractions = cast("tuple[float, float, float]", tuple(float(v) for v in splits.split(",")))  # ImportConfig counts them
    except ValueError:
        raise ConfigError(f"--splits must be three fractions TRAIN,VAL,TEST, got {splits!r}") from None
    cfg = ImportConfig(cityscapes_classes=cityscapes_classes, split_fractions=fractions, images=images,
                       depth=depth, intrinsics=intrinsics, depth_scale_m=depth_scale)
    emit(import_dataset(fmt, src, out, cfg))


@data.command("capture")
@click.argument("out", type=click.Path(file_okay=False))
@click.option("--camera", default="realsense", show_default=True,
              help="realsense[:SERIAL], synth[:SEED] or dir:PATH (the same sources as the runtime).")
@click.option("--count", default=10, show_default=True, help="Frames to save.")
@click.option("--interval", default=0.0, show_default=True, help="Seconds between frames (time to move objects).")
@click.option("--size", default="640x480", show_default=True, help="Camera stream size, WIDTHxHEIGHT.")
def data_capture(out: str, camera: str, count: int, interval: float, size: str) -> None:
    """Save aligned RGB + depth + intrinsics.json from a camera into OUT, for annotation (e.g. CVAT)."""
    from edgepick.cli.cameras import open_camera
    from edgepick.data.capture import capture, check_count

    source = camera.partition(":")[2] if camera.startswith("dir:") else None
    check_output(out, "OUT", kind="dir", inputs=(source,))
    if count < 1 or not (math.isfinite(interval) and interval >= 0):
        raise ConfigError("--count must be at least 1 and --interval 0 or more seconds")
    check_count(count)
    emit(capture(open_camera(camera, parse_size(size)), out, count, interval))


