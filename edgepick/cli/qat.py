"""`edgepick quantize qat|hybrid`: thin click shells over edgepick.quant's QaT passes (the group and
the options all quantize commands share are in cli/quant.py)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import click

from edgepick.cli.options import choice, default_of, emit, epoch_subset, with_options
from edgepick.cli.quant import check_onnx_out_flag, common, configs_of
from edgepick.errors import ConfigError
from edgepick.files import check_output
from edgepick.models.config import Arch
from edgepick.quant.config import DEFAULT_CALIB_IMAGES, QatOptions
from edgepick.train.config import Device, TrainConfig

# QaT and hybrid-QaT
qat_options = [
    click.option("--weight-averaging", default=default_of(QatOptions, "weight_averaging"), show_default=True,
                 help="Moving-average constant of the QaT weight ranges; 1.0 = each step's own range."),
]


@click.command("qat")
@click.option("--data", "data_dir", required=True, type=click.Path())
@click.option("--run", "run_dir", default=None, type=click.Path(file_okay=False),
              help="Folder for the QaT run's checkpoints [default: OUT with .run].")
@click.option("--arch", default=default_of(TrainConfig, "arch"), show_default=True, type=choice(Arch))
@click.option("--epochs", default=default_of(TrainConfig, "epochs"), show_default=True)
@click.option("--batch-size", default=default_of(TrainConfig, "batch_size"), show_default=True)
@click.option("--lr", default=default_of(TrainConfig, "lr"), show_default=True)
@click.option("--size", default="640x480", show_default=True,
              help="Model input size, WIDTHxHEIGHT (multiples of 8); images are resized to it.")
@click.option("--device", default=default_of(TrainConfig, "device"), show_default=True, type=choice(Device))
@click.option("--seed", default=default_of(TrainConfig, "seed"), show_default=True)
@with_options(epoch_subset)
@with_options(qat_options)
@with_options(common)
def quantize_qat_cmd(data_dir: str, run_dir: str | None, arch: str, epochs: int, batch_size: int, lr: float,
                     size: str, device: str, seed: int, epoch_images: int, val_images: int, out: str,
                     weight_bits: str, keep_float: str, weight_averaging: float) -> None:
    """QaT from scratch: train with fake-quant for all epochs (GPU if there is one; fp32, no AMP),
    observers and BN statistics frozen for the last 30% of the steps, then export the int8 model
    of the epoch with the best val mIoU."""
    from edgepick.cli.options import check_data_orientation, model_size
    from edgepick.quant.pt2e.passes import quantize_qat

    check_onnx_out_flag(out, data_dir)
    input_size = model_size(size)
    check_data_orientation(data_dir, input_size)
    run = run_dir or str(Path(out).with_suffix(".run"))
    cfg = TrainConfig(data=data_dir, out=run, arch=Arch(arch), epochs=epochs, batch_size=batch_size, lr=lr,
                      size=input_size, device=Device(device), seed=seed, epoch_images=epoch_images,
                      val_images=val_images)
    check_output(run, "--run", kind="dir", inputs=(data_dir, out))
    emit(quantize_qat(cfg, out, **configs_of(weight_bits=weight_bits, keep_float=keep_float,
                                             weight_averaging=weight_averaging)))


@click.command("hybrid")
@click.argument("run", metavar="RUN", type=click.Path(file_okay=False))
@click.option("--data", "data_dir", required=True, type=click.Path())
@click.option("--qat-fraction", required=True, type=float,
              help="p in (0, 1): the last p of RUN's epoch budget is trained with QaT.")
@click.option("--run", "qat_run", default=None, type=click.Path(file_okay=False),
              help="Folder for the QaT phase's checkpoints [default: OUT with .run].")
@click.option("--freeze-at", default=default_of(QatOptions, "freeze_at"), show_default=True,
              help="Share of the QaT steps after which observers and BN statistics are frozen (1.0: never).")
@click.option("--fresh-optimizer", is_flag=True,
              help="Start the QaT phase with a fresh AdamW instead of the float run's moments (for comparison).")
@click.option("--calib-images", default=None, type=int,
              help=f"Start the activation ranges from static PTQ's (percentile over N train images) [default: "
                   f"{DEFAULT_CALIB_IMAGES}, or the whole train split if smaller]; 0: from the first batch's min/max.")
@click.option("--hold-ranges/--moving-ranges", default=None,
              help="Keep the calibrated ranges for the whole QaT phase, or let the observers move them "
                   "[default: hold when calibrated].")
@click.option("--device", default=default_of(TrainConfig, "device"), show_default=True, type=choice(Device),
              help="Where the QaT phase trains (auto: the GPU if there is one), whatever device RUN used.")
@with_options(qat_options)
@with_options(common)
def quantize_hybrid_cmd(run: str, data_dir: str, qat_fraction: float, qat_run: str | None, out: str,
                        weight_bits: str, keep_float: str, freeze_at: float, fresh_optimizer: bool,
                        calib_images: int | None, hold_ranges: bool | None, device: str,
                        weight_averaging: float) -> None:
    """Hybrid-QaT: continue float RUN from its epoch_NNN.pt at (1 - p) of its budget E and train
    the last pE epochs with QaT (train RUN with --keep-epochs at the switch points, e.g. 90,95,99
    for p = 10%, 5%, 1% of 100 epochs). Exports the QaT epoch with the best val mIoU, as export
    takes a float RUN's best.pt. Reports the wall time of each phase."""
    from edgepick.quant.pt2e.passes import quantize_hybrid

    check_onnx_out_flag(out, run, data_dir)
    check_output(qat_run or str(Path(out).with_suffix(".run")), "--run", kind="dir", inputs=(run, data_dir, out))
    if calib_images is not None and (calib_images < 0 or (hold_ranges and not calib_images)):
        raise ConfigError("--calib-images must be 0 (off) or positive, and --hold-ranges needs it")
    configs = configs_of(weight_bits=weight_bits, keep_float=keep_float, weight_averaging=weight_averaging,
                         freeze_at=freeze_at)
    emit(quantize_hybrid(run, data_dir, out, qat_fraction, _drawn(run, data_dir, calib_images), **configs, qat_run=qat_run,
                         carry_optimizer=not fresh_optimizer, hold_ranges=hold_ranges, device=Device(device)))


def _drawn(run: str, data: str, count: int | None) -> Iterator[Any]:
    """--calib-images train images (0: none) drawn with RUN's seed, read only once quantize_hybrid has
    checked the run and the settings, so that a refusal stays one line."""
    from edgepick.quant.pt2e.images import run_images

    if count != 0:
        yield from run_images(run, data, count)
