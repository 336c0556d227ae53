"""Where hybrid-QaT's first-epoch drop comes from, without any weight update: one float run, then
the val mIoU of int8 models converted from it in ways that differ only in their activation ranges.

    python benchmarks/hybrid_start.py [--run RUN --data DATA] [--hybrid P] [--out FILE.md | --save]

Without --run it trains a small float model on CPU first. Rows:
- static PTQ, percentile (the default) and minmax ranges, calibrated on plain train images;
- static PTQ, minmax ranges calibrated on augmented training batches (what QaT's observers see);
- the QaT graph after K training-mode forward passes over augmented batches (observers and BN
  statistics move, weights do not), then frozen and converted: hybrid-QaT's starting point,
  from the first batches' min/max (as before) or from static PTQ's ranges (--calib-images).
With --hybrid P (RUN trained with --keep-epochs at (1 - P)E), also the whole hybrid-QaT pass with
each start, scored by `edgepick eval` on the val and test splits.
"""

from __future__ import annotations

import argparse
import copy
import sys
import tempfile
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from _common import add_output, emit, machine_line  # noqa: E402

from edgepick.cli.options import model_size  # noqa: E402
from edgepick.data.native import NativeDataset  # noqa: E402
from edgepick.data.synth import SynthConfig, synthesize  # noqa: E402
from edgepick.geometry import Size  # noqa: E402
from edgepick.metrics import confusion_matrix, segmentation_metrics  # noqa: E402
from edgepick.models.deeplabv3 import LogitsNet  # noqa: E402
from edgepick.quant.config import QuantConfig  # noqa: E402
from edgepick.quant.pt2e.graph import as_input, convert, prepare  # noqa: E402
from edgepick.quant.pt2e.images import model_images  # noqa: E402
from edgepick.quant.pt2e.qat import calibrate_activations, to_eval  # noqa: E402
from edgepick.train.checkpoint import load_model  # noqa: E402
from edgepick.train.data import augment  # noqa: E402
from edgepick.train.loop import TrainConfig, train  # noqa: E402


def val_miou(net, data: Path, size: Size, count: int) -> float:
    """mIoU of a logits net over COUNT val images (area-resized like calibration; masks nearest)."""
    import cv2

    ds = NativeDataset.open(data, "val")
    n = len(ds.classes)
    cm = np.zeros((n, n), np.int64)
    h, w = size.hw
    with torch.no_grad():
        for i in ds.ids[:count]:
            rgb = cv2.resize(ds.rgb(i), (w, h), interpolation=cv2.INTER_AREA)
            mask = cv2.resize(ds.mask(i), (w, h), interpolation=cv2.INTER_NEAREST)
            pred = net(as_input(rgb)).argmax(1)[0].numpy()
            cm += confusion_matrix(mask[None], pred[None], n)
    return 100 * segmentation_metrics(cm)["miou"]


def train_batches(data: Path, size: Size, count: int, batch: int, seed: int = 0) -> list[torch.Tensor]:
    """COUNT augmented training batches, as the training loop makes them."""
    images = np.stack(model_images(data, "train", count * batch, size, seed))
    x = torch.from_numpy(images).permute(0, 3, 1, 2).float()
    gen = torch.Generator().manual_seed(seed)
    dummy = torch.zeros(x.shape[0], *size.hw, dtype=torch.long)
    out = []
    for k in range(count):
        xb, _ = augment(x[k * batch:(k + 1) * batch], dummy[k * batch:(k + 1) * batch], gen)
        out.append(xb)
    return out


def static(model, size, images: list[torch.Tensor], method: str) -> torch.nn.Module:
    prepared = prepare(copy.deepcopy(model), QuantConfig(calib_method=method), size, qat=False)
    with torch.no_grad():
        for batch in images:
            for x in batch:  # the static graph is exported for one image
                prepared(x[None])
    return convert(prepared)


def qat_start(model, size, batches: list[torch.Tensor], calib: list[np.ndarray] | None = None,
              hold: bool = False) -> torch.nn.Module:
    from torchao.quantization.pt2e import disable_observer

    prepared = prepare(copy.deepcopy(model), QuantConfig(), size, qat=True)
    if calib is not None:
        calibrate_activations(prepared, calib, hold=hold)
    with torch.no_grad():
        for x in batches:
            prepared(x)
    prepared.apply(disable_observer)
    to_eval(prepared)
    return convert(prepared)


def weight_clipping(model, size, batches: list[torch.Tensor]) -> str:
    """After training-mode passes (no update), how many output channels' largest QaT weight
    (w * gamma / sqrt(running_var + eps) with the conv-BN fusion) lies beyond its moving-average range."""
    from torchao.quantization.pt2e import FakeQuantizeBase

    prepared = prepare(copy.deepcopy(model), QuantConfig(), size, qat=True)
    fqs = {n: m for n, m in prepared.named_modules() if isinstance(m, FakeQuantizeBase) and m.is_per_channel}
    seen: dict[str, torch.Tensor] = {}
    hooks = [m.register_forward_pre_hook(lambda mod, a, n=n: seen.__setitem__(n, a[0].detach().clone()))
             for n, m in fqs.items()]
    with torch.no_grad():
        for x in batches:
            prepared(x)
    for h in hooks:
        h.remove()
    ratio = torch.cat([seen[n].abs().flatten(1).max(1).values
                       / torch.maximum(m.activation_post_process.max_val.abs(), m.activation_post_process.min_val.abs())
                       .clamp_min(1e-12) for n, m in fqs.items()])
    return (f"after {len(batches)} training-mode passes: {float((ratio > 1.01).float().mean()):.1%} of {ratio.numel()} "
            f"output channels have their largest weight over its range by > 1%; max {float(ratio.max()):.3f}x, "
            f"99th percentile {float(ratio.quantile(0.99)):.3f}x")


def hybrid_ab(run: Path, data: Path, fraction: float, tmp: Path) -> dict[str, tuple[float, float, float | str]]:
    """fp32 and hybrid-QaT from each start: first-batch ranges, calibrated, calibrated and held."""
    from edgepick.evaluation import evaluate
    from edgepick.export.onnx_export import export_checkpoint
    from edgepick.quant.pt2e.images import run_images
    from edgepick.quant.pt2e.passes import quantize_hybrid
    from edgepick.train.config import Device

    def scores(path: Path) -> tuple[float, float]:
        return tuple(100 * evaluate(path, data, split, progress=False)["miou"] for split in ("val", "test"))

    export_checkpoint(run, tmp / "fp32.onnx")
    rows = {"fp32": (*scores(tmp / "fp32.onnx"), "")}
    images = run_images(run, data, 64)
    for label, (calib, hold) in {"first-batch ranges, moving (--calib-images 0)": ([], None),
                                 "calibrated start, 64 images": (images, False),
                                 "calibrated start, held (the default)": (images, True)}.items():
        out = tmp / f"h{len(rows)}.onnx"
        result = quantize_hybrid(run, data, out, fraction, calib, progress=False, device=Device.CPU, hold_ranges=hold)
        rows[f"hybrid, {label}"] = (*scores(out), result.qat_phase_s)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--run", default=None, help="float RUN or checkpoint (default: train one here)")
    ap.add_argument("--data", default=None)
    ap.add_argument("--epochs", type=int, default=40)
    ap.add_argument("--size", default="160x128", help="model input WIDTHxHEIGHT")
    ap.add_argument("--batches", type=int, default=8, help="augmented batches for the QaT start")
    ap.add_argument("--batch-size", type=int, default=8)
    ap.add_argument("--val", type=int, default=40, help="val images scored")
    ap.add_argument("--hybrid", type=float, default=None, help="also run hybrid-QaT with this fraction")
    ap.add_argument("--clipping-only", action="store_true", help="only the weight-range clipping line")
    add_output(ap)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        if args.run is None:
            data = Path(tmp) / "data"
            synthesize(data, SynthConfig(scenes=360, width=320, height=240, seed=5, splits=(300, 40, 20)),
                       progress=False)
            size = model_size(args.size)
            run = Path(tmp) / "float"
            train(TrainConfig(data=str(data), out=str(run), epochs=args.epochs, batch_size=8, size=size, lr=2e-3,
                              device="cpu"), progress=False)
        else:
            run, data = Path(args.run), Path(args.data)
        model, ckpt = load_model(run)
        size = ckpt.input_size
        calib = model_images(data, "train", 64, size)
        plain = [as_input(r) for r in calib]
        batches = train_batches(data, size, args.batches, args.batch_size)
        clipping = weight_clipping(model, size, batches)
        if args.clipping_only:
            emit(f"Command: `python benchmarks/hybrid_start.py {' '.join(sys.argv[1:])}`\n\n- {clipping}\n", args)
            return
        rows = {"fp32": val_miou(LogitsNet(copy.deepcopy(model)).eval(), data, size, args.val),
                "static, percentile, 64 plain images": val_miou(static(model, size, plain, "percentile"), data, size, args.val),
                "static, minmax, 64 plain images": val_miou(static(model, size, plain, "minmax"), data, size, args.val),
                f"static, minmax, {args.batches} augmented batches": val_miou(
                    static(model, size, batches, "minmax"), data, size, args.val),
                f"static, percentile, {args.batches} augmented batches": val_miou(
                    static(model, size, batches, "percentile"), data, size, args.val),
                f"QaT graph after {args.batches} training-mode passes, no update": val_miou(
                    qat_start(model, size, batches), data, size, args.val),
                f"QaT graph, calibrated start (percentile, 64 plain images), {args.batches} passes, ranges moving":
                    val_miou(qat_start(model, size, batches, calib), data, size, args.val),
                f"QaT graph, calibrated start, {args.batches} passes, ranges held": val_miou(
                    qat_start(model, size, batches, calib, hold=True), data, size, args.val)}
        hybrid_rows = hybrid_ab(run, data, args.hybrid, Path(tmp)) if args.hybrid else {}
        source = "trained here" if args.run is None else str(run)
    lines = ["# Hybrid-QaT's starting point: activation ranges", "",
             "Command: `python benchmarks/hybrid_start.py " + " ".join(sys.argv[1:]) + "`", "",
             f"- {machine_line()}; float model {source}, input {size}; "
             f"batches of {args.batch_size}; mIoU on {args.val} val images", "",
             "| int8 model | val mIoU (%) | vs fp32 (pp) |", "|---|---|---|"]
    for label, value in rows.items():
        delta = "" if label == "fp32" else f"{value - rows['fp32']:+.2f}"
        lines.append(f"| {label} | {value:.2f} | {delta} |")
    lines += ["", f"QaT weight ranges, {clipping}"]
    if hybrid_rows:
        lines += ["", f"## Hybrid-QaT {args.hybrid:.0%} from {run}, by start", "",
                  "`edgepick eval` of each ONNX (val: the whole val split; test: the whole test split).", "",
                  "| model | val mIoU (%) | test mIoU (%) | QaT phase (s) |", "|---|---|---|---|"]
        for label, (val, test, seconds) in hybrid_rows.items():
            lines.append(f"| {label} | {val:.2f} | {test:.2f} | {seconds} |")
    emit("\n".join(lines) + "\n", args)


if __name__ == "__main__":
    main()
