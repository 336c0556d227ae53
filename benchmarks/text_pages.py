"""Synthetic document photos (printed lines on a tinted page, some blur and noise): calibration and
check images for a text-detection model, such as the PP-OCR detector benchmarks/peers_onnx.py
measures.

    python benchmarks/text_pages.py OUT --count 48 --size 640x480 --seed 0
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

CHARS = list("ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789 .,:-")


def page(rng: np.random.Generator, width: int, height: int) -> np.ndarray:
    """One BGR page: 6-14 lines of random text in OpenCV's fonts, sizes and dark colours."""
    img = np.empty((height, width, 3), np.uint8)
    img[:] = rng.integers(170, 256, 3)
    y = int(rng.integers(20, 50))
    while y < height - 10:
        scale = float(rng.uniform(0.5, 1.3))
        text = "".join(rng.choice(CHARS, int(rng.integers(6, 30))))
        cv2.putText(img, text, (int(rng.integers(0, width // 3)), y), int(rng.integers(0, 8)), scale,
                    tuple(int(v) for v in rng.integers(0, 100, 3)), int(rng.integers(1, 3)), cv2.LINE_AA)
        y += int(scale * 40 + rng.integers(5, 30))
    if rng.random() < 0.5:
        img = cv2.GaussianBlur(img, (0, 0), float(rng.uniform(0.3, 1.2)))
    noise = rng.normal(0, rng.uniform(0, 6), img.shape)
    return np.clip(img + noise, 0, 255).astype(np.uint8)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out")
    ap.add_argument("--count", type=int, default=48)
    ap.add_argument("--size", default="640x480", help="WIDTHxHEIGHT")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    width, height = (int(v) for v in args.size.split("x"))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(args.seed)
    for k in range(args.count):
        cv2.imwrite(str(out / f"{k:03d}.png"), page(rng, width, height))
    print(f"{args.count} pages in {out}")


if __name__ == "__main__":
    main()
