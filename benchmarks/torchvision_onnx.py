"""A torchvision segmentation model (a family edgepick's code does not build), trained briefly on an
edgepick data set by a plain torch loop and exported as a float ONNX with dynamic dims, ImageNet
normalisation expected at its input: a model from elsewhere for benchmarks/peers_onnx.py.

    pip install torchvision     # the build that matches your torch
    python benchmarks/torchvision_onnx.py --arch lraspp_mobilenet_v3_large --data DATA --epochs 3 --out lraspp.onnx
    python benchmarks/torchvision_onnx.py ... --epochs 15 --device cuda    # train on a GPU
"""

from __future__ import annotations

import argparse
import time
import warnings

import cv2
import numpy as np
import torch
from torch import nn

from edgepick.data.native import NativeDataset

MEAN, STD = (0.485, 0.456, 0.406), (0.229, 0.224, 0.225)


class Out(nn.Module):
    """torchvision's {"out": ...} as the one output tensor."""

    def __init__(self, model: nn.Module):
        super().__init__()
        self.model = model

    def forward(self, x):
        return self.model(x)["out"]


def batch(ds: NativeDataset, ids: list[str], size: tuple[int, int]) -> tuple[torch.Tensor, torch.Tensor]:
    """Images normalised as ImageNet models expect, and their masks, at SIZE (W, H)."""
    x = np.stack([cv2.resize(ds.rgb(i), size, interpolation=cv2.INTER_AREA) for i in ids]).astype(np.float32) / 255
    y = np.stack([cv2.resize(ds.mask(i), size, interpolation=cv2.INTER_NEAREST) for i in ids]).astype(np.int64)
    x = (x - np.asarray(MEAN, np.float32)) / np.asarray(STD, np.float32)
    return torch.from_numpy(x.transpose(0, 3, 1, 2).copy()), torch.from_numpy(y)


def recompute_batchnorm(model: nn.Module, ds: NativeDataset, size: tuple[int, int], batch_size: int,
                        device: str = "cpu") -> None:
    """BatchNorm's running statistics recomputed as exact averages over the train set: a short run
    leaves moving averages far from the weights it ends with, and the eval-mode model then
    predicts one class."""
    norms = [m for m in model.modules() if isinstance(m, nn.modules.batchnorm._BatchNorm)]
    for m in norms:
        m.reset_running_stats()
        m.momentum = None  # a cumulative average
    model.train()
    with torch.no_grad():
        for k in range(0, len(ds.ids), batch_size):
            model(batch(ds, ds.ids[k:k + batch_size], size)[0].to(device))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--arch", default="lraspp_mobilenet_v3_large", choices=["lraspp_mobilenet_v3_large", "fcn_resnet50"])
    ap.add_argument("--data", required=True)
    ap.add_argument("--epochs", type=int, default=3)
    ap.add_argument("--size", default="640x480", help="WIDTHxHEIGHT of training")
    ap.add_argument("--batch-size", type=int, default=8)
    ap.add_argument("--lr", type=float, default=1e-3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--opset", type=int, default=17)
    ap.add_argument("--device", default="cpu", help="cpu or cuda (training only; the export runs on the CPU)")
    ap.add_argument("--out", required=True)
    args = ap.parse_args()

    from torchvision.models import segmentation

    torch.manual_seed(args.seed)
    train, val = NativeDataset.open(args.data, "train"), NativeDataset.open(args.data, "val")
    size = tuple(int(v) for v in args.size.split("x"))
    model = getattr(segmentation, args.arch)(weights=None, weights_backbone=None, num_classes=len(train.classes))
    model.to(args.device)
    opt = torch.optim.AdamW(model.parameters(), lr=args.lr)
    rng = np.random.default_rng(args.seed)
    for epoch in range(args.epochs):
        model.train()
        order, t0, losses = rng.permutation(len(train.ids)), time.time(), []
        for k in range(0, len(order), args.batch_size):
            x, y = batch(train, [train.ids[i] for i in order[k:k + args.batch_size]], size)
            x, y = x.to(args.device), y.to(args.device)
            loss = nn.functional.cross_entropy(model(x)["out"], y, ignore_index=255)
            opt.zero_grad()
            loss.backward()
            opt.step()
            losses.append(loss.item())
        recompute_batchnorm(model, train, size, args.batch_size, args.device)
        model.eval()
        with torch.no_grad():
            x, y = batch(val, val.ids, size)
            acc = float((model(x.to(args.device))["out"].argmax(1).cpu() == y).float().mean())
        print(f"epoch {epoch + 1}/{args.epochs}: loss {np.mean(losses):.3f}, val pixel acc {acc:.3f}, "
              f"{time.time() - t0:.0f} s", flush=True)
    with warnings.catch_warnings(), torch.no_grad():
        warnings.simplefilter("ignore")
        torch.onnx.export(Out(model.cpu().eval()), torch.zeros(1, 3, size[1], size[0]), args.out, dynamo=False,
                          opset_version=args.opset, input_names=["input"], output_names=["out"],
                          dynamic_axes={"input": {0: "n", 2: "h", 3: "w"}, "out": {0: "n", 2: "h", 3: "w"}})
    print(f"written to {args.out}")


if __name__ == "__main__":
    main()
