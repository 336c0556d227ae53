"""`edgepick train`, `eval` and `demo`: float training, evaluation, the end-to-end demo."""

from __future__ import annotations

import json
from pathlib import Path

import click

from edgepick.cli.options import check_data_orientation, choice, default_of, emit, epoch_subset, model_size, with_options
from edgepick.data.config import Split
from edgepick.demo import run_demo
from edgepick.errors import ConfigError
from edgepick.files import atomic_write, check_output
from edgepick.models.config import Arch, ColorSpace, OutputStride, Variant
from edgepick.train.config import Augment, Device, TrainConfig


@click.command()
@click.argument("data_dir", metavar="DATA", type=click.Path())
@click.option("--out", required=True, type=click.Path(file_okay=False), help="RUN folder for checkpoints and metrics.")
@click.option("--arch", default=default_of(TrainConfig, "arch"), show_default=True, type=choice(Arch),
              help="The model family and its backbone (thesis Table 5.4: segnet, fcn-resnet101, unet, deeplabv3-*; "
                   "and lraspp-mobilenetv3, ddrnet23-slim for laptop CPUs).")
@click.option("--variant", default=default_of(TrainConfig, "variant"), show_default=True, type=choice(Variant),
              help="edge (the MobileNetV3 architectures): MobileNetV3 without SE and hardswish, 128-channel ASPP "
                   "(quantization-friendly; not torchvision-compatible).")
@click.option("--epochs", default=None, type=int,
              help=f"Epoch budget [default: {default_of(TrainConfig, 'epochs')}; on --resume: the run's own].")
@click.option("--batch-size", default=default_of(TrainConfig, "batch_size"), show_default=True)
@click.option("--lr", default=default_of(TrainConfig, "lr"), show_default=True,
              help="AdamW learning rate (poly decay, short warm-up).")
@click.option("--device", default=default_of(TrainConfig, "device"), show_default=True, type=choice(Device))
@click.option("--size", default="640x480", show_default=True,
              help="Model input size, WIDTHxHEIGHT (multiples of 8); images are resized to it.")
@click.option("--colorspace", default=default_of(TrainConfig, "colorspace"), show_default=True, type=choice(ColorSpace))
@click.option("--output-stride", default=default_of(TrainConfig, "output_stride"), show_default=True,
              type=choice(OutputStride))
@click.option("--aux-loss/--no-aux-loss", default=default_of(TrainConfig, "aux_loss"), show_default=True,
              help="FCN auxiliary head (weight 0.4).")
@click.option("--keep-epochs", default="", help="Comma-separated epochs whose checkpoints are kept (hybrid-QaT switch points).")
@click.option("--backbone-weights", default=None, type=click.Path(dir_okay=False),
              help="Backbone state dict to start from (the architectures with a MobileNetV3 or ResNet backbone).")
@click.option("--augment", default=default_of(TrainConfig, "augment"), show_default=True, type=choice(Augment),
              help="basic: brightness, contrast, saturation and colour-cast jitter, flips, scale. lights: also "
                   "relights about a third of the images by a dim room and one low red-orange lamp (not better "
                   "under the synthetic hazard light than basic: benchmarks/results/lighting-augment/).")
@with_options(epoch_subset)
@click.option("--workers", default=default_of(TrainConfig, "workers"), show_default=True,
              help="Data loader workers; -1 = decode once into memory (4 workers on GPU when that does not fit).")
@click.option("--seed", default=default_of(TrainConfig, "seed"), show_default=True)
@click.option("--resume", is_flag=True, help="Continue RUN from its last.pt (losing at most one epoch).")
def train(data_dir: str, out: str, arch: Arch, variant: Variant, epochs: int | None, batch_size: int, lr: float,
          device: Device, size: str, colorspace: ColorSpace, output_stride: OutputStride, aux_loss: bool,
          keep_epochs: str, backbone_weights: str | None, augment: Augment, epoch_images: int, val_images: int,
          workers: int, seed: int, resume: bool) -> None:
    """Train a float segmentation model on DATA (CPU, one GPU with bf16 AMP, or DDP under torchrun).

    \b
    RUN holds, after each epoch:
      last.pt        weights, AdamW and schedule state: what --resume continues from
      best.pt        the weights of the epoch with the best validation mIoU (what export and
                     quantize static take), without the optimizer state: a third of last.pt
      epoch_NNN.pt   copies of last.pt at --keep-epochs (hybrid-QaT's switch points)
      metrics.json   per-epoch loss, pixel accuracy, mIoU, per-class IoU and timings
    Multi-GPU: torchrun --nproc_per_node N -m edgepick train DATA --out RUN ...
    --resume continues RUN on DATA (the same data set, at any path) after a kill.
    """
    from edgepick.train.run import Run
    from edgepick.train.torchrun import dist_env

    dist_env()  # every mistake below is found before torch is imported
    try:
        keep = tuple(sorted({int(v) for v in keep_epochs.split(",") if v.strip()}))
    except ValueError:
        raise ConfigError(f"--keep-epochs must be comma-separated integers, got {keep_epochs!r}") from None
    input_size = model_size(size)
    if resume:
        check_output(out, "--out", kind="dir", inputs=(data_dir,), reuse="train")
        from edgepick.train.loop import resume_run

        result = resume_run(out, data_dir, epochs)
    else:
        cfg = TrainConfig(data=data_dir, out=out, arch=arch, variant=variant, batch_size=batch_size, lr=lr,
                          size=input_size, colorspace=colorspace, output_stride=output_stride, aux_loss=aux_loss,
                          device=device, keep_epochs=keep, backbone_weights=backbone_weights,
                          epoch_images=epoch_images, val_images=val_images, workers=workers, seed=seed, augment=augment,
                          epochs=default_of(TrainConfig, "epochs") if epochs is None else epochs)
        Run(out).check_new()
        check_output(out, "--out", kind="dir", inputs=(data_dir,))
        check_data_orientation(data_dir, input_size)
        from edgepick.train.loop import train as run_train

        result = run_train(cfg)
    if result is not None:
        emit(result.to_dict())


@click.command("eval")
@click.argument("model", type=click.Path())
@click.argument("data_dir", metavar="DATA", type=click.Path())
@click.option("--split", default=Split.TEST.value, show_default=True, type=choice(Split))
@click.option("--out", default=None, type=click.Path(dir_okay=False), help="Also write the JSON here.")
def eval_cmd(model: str, data_dir: str, split: Split, out: str | None) -> None:
    """Pixel accuracy, per-class IoU, mIoU and confusion matrix of MODEL (checkpoint, RUN or ONNX) as JSON."""
    from edgepick.evaluation import evaluate

    if out is not None:
        check_output(out, "--out", inputs=(model, data_dir))
    result = evaluate(model, data_dir, split)
    if out is not None:
        atomic_write(out, json.dumps(result, indent=1))
    emit(result)



@click.command()
@click.option("--workdir", default="demo-out", show_default=True, type=click.Path(file_okay=False),
              help="Folder for everything the demo makes. A new or empty folder, or one an earlier demo made (its "
                   "old contents are removed first); any other folder is refused, as is the working folder.")
@click.option("--scenes", default=default_of(run_demo, "scenes"), show_default=True,
              help="Synthetic scenes to make, split 2:1:1 into train, val and test.")
@click.option("--epochs", default=default_of(run_demo, "epochs"), show_default=True,
              help="The float run's epoch budget (and QaT from scratch's); hybrid-QaT trains its last 1/5/10%.")
def demo(workdir: str, scenes: int, epochs: int) -> None:
    """The main job on an embedded default, about 5 minutes on 2 cores: synthetic data, one small CPU
    float run, evaluation, the int8 passes from it (static PTQ, QaT from scratch, hybrid-QaT
    1/5/10%) as ONNX files, pick cycles on the simulated robot, and the bench tables (thesis Tables
    5.5 and 5.6, with grasp success in the synthetic cell)."""
    if epochs < 100:
        raise ConfigError(f"--epochs {epochs}: the demo needs at least 100 (hybrid-QaT's 1% must be a whole epoch)")
    if scenes < 30:
        raise ConfigError(f"--scenes {scenes}: the demo needs at least 30 (train, val and test splits)")
    check_output(workdir, "--workdir", kind="dir", reuse="demo")
    from edgepick.data.synth import SynthConfig, check_room

    check_room(SynthConfig(scenes=scenes), Path(workdir) / "data")  # before the demo's first step line
    run_demo(Path(workdir), scenes=scenes, epochs=epochs)

