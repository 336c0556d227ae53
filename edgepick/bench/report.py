"""Write the bench table as Markdown, CSV, JSON and a PNG of mIoU against latency (OpenCV
drawing, no plotting library)."""

from __future__ import annotations

import csv
import json
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from edgepick.bench.measure import Row

HEADER_55 = ["Mode", "Pixel Acc (%)", "mIoU (%)", "Inference p50 (ms)", "p95 (ms)", "Training time", "Size (MB)"]
HEADER_56 = ["Mode", "Pipeline p50 (ms)", "p95 (ms)", "Size (MB)"]


def duration(seconds: float | None) -> str:
    """Thesis-style training time: '4 d 20 h', '1 h 05 min', '3 min 20 s', '42 s'."""
    if seconds is None:
        return "-"
    s = int(round(seconds))
    d, h, m = s // 86400, s % 86400 // 3600, s % 3600 // 60
    if d:
        return f"{d} d {h} h"
    if h:
        return f"{h} h {m:02d} min"
    if m:
        return f"{m} min {s % 60:02d} s"
    return f"{s} s"


def _pct(v: float | None) -> str:
    return "-" if v is None else f"{100 * v:.2f}"


def table55_rows(rows: list[Row]) -> list[list[str]]:
    return [[r.mode, _pct(r.pixel_acc), _pct(r.miou), f"{r.p50_ms:.1f}", f"{r.p95_ms:.1f}", duration(r.train_time_s),
             f"{r.size_mb:.2f}"] for r in rows]


def table56_rows(rows: list[Row]) -> list[list[str]]:
    return [[r.mode, f"{r.pipeline_p50_ms:.1f}", f"{r.pipeline_p95_ms:.1f}", f"{r.size_mb:.2f}"]
            for r in rows if r.pipeline_p50_ms is not None]


def markdown(header: list[str], body: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(row) + " |" for row in body]
    return "\n".join(lines)


def draw_axes(img: np.ndarray, frame: tuple[int, int, int, int], xlim: tuple[float, float],
              ylim: tuple[float, float], xticks: list[float], yticks: list[float], formats: tuple[str, str],
              titles: tuple[str, str]) -> Callable[[float, float], tuple[int, int]]:
    """Grid, tick labels, frame and axis titles of a chart in FRAME (left, right, top, bottom) of IMG;
    returns the data -> pixel mapping, for the bench's PNGs (OpenCV only, no plotting library)."""
    h, w = img.shape[:2]
    left, right, top, bottom = frame
    (x0, x1), (y0, y1) = xlim, ylim

    def px(x: float, y: float) -> tuple[int, int]:
        return (int(left + (x - x0) / (x1 - x0) * (right - left)), int(bottom - (y - y0) / (y1 - y0) * (bottom - top)))

    black, grey = (0, 0, 0), (200, 200, 200)
    for gx in xticks:
        cv2.line(img, px(gx, y0), px(gx, y1), grey, 1)
        cv2.putText(img, formats[0].format(gx), (px(gx, y0)[0] - 12, bottom + 20), cv2.FONT_HERSHEY_SIMPLEX, 0.45,
                    black, 1)
    for gy in yticks:
        cv2.line(img, px(x0, gy), px(x1, gy), grey, 1)
        cv2.putText(img, formats[1].format(gy), (left - 60, px(x0, gy)[1] + 5), cv2.FONT_HERSHEY_SIMPLEX, 0.45,
                    black, 1)
    cv2.rectangle(img, (left, top), (right, bottom), black, 1)
    cv2.putText(img, titles[0], (w // 2 - 80, h - 15), cv2.FONT_HERSHEY_SIMPLEX, 0.55, black, 1)
    cv2.putText(img, titles[1], (10, top - 15), cv2.FONT_HERSHEY_SIMPLEX, 0.55, black, 1)
    return px


def plot(rows: list[Row], path: Path, size: tuple[int, int] = (800, 520)) -> None:
    """mIoU (%) against inference p50 (ms), one labelled point per row."""
    w, h = size
    img = np.full((h, w, 3), 255, np.uint8)
    left, right, top, bottom = 80, w - 30, 40, h - 60
    pts = [(r.p50_ms, 100 * (r.miou or 0.0), r.mode) for r in rows]
    xs, ys = [p[0] for p in pts] or [0.0], [p[1] for p in pts] or [0.0]
    x0, x1 = 0.0, max(xs) * 1.15 + 1e-6
    y0, y1 = max(0.0, min(ys) - 5), min(100.0, max(ys) + 5) + 1e-6
    px = draw_axes(img, (left, right, top, bottom), (x0, x1), (y0, y1), [x0 + k * (x1 - x0) / 5 for k in range(6)],
                   [y0 + k * (y1 - y0) / 5 for k in range(6)], ("{:.0f}", "{:.1f}"), ("inference p50 (ms)", "mIoU (%)"))
    colours = [(200, 80, 30), (30, 140, 30), (30, 30, 200), (160, 30, 160), (0, 140, 200), (90, 90, 90)]
    for i, (x, y, label) in enumerate(pts):
        c = colours[i % len(colours)]
        cv2.circle(img, px(x, y), 6, c, -1, cv2.LINE_AA)
        cv2.putText(img, label, (px(x, y)[0] + 9, px(x, y)[1] - 8 + 14 * (i % 2)), cv2.FONT_HERSHEY_SIMPLEX, 0.45, c,
                    1, cv2.LINE_AA)
    if not cv2.imwrite(str(path), img):
        raise OSError(f"could not write {path}")


def write_reports(rows: list[Row], out_dir: str | Path, context: dict) -> dict[str, str]:
    """table.md / .csv / .json and mIoU-latency.png in OUT_DIR; returns their paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    md = [f"# {context.get('title', 'edgepick bench')}", ""]
    md += [f"- {k}: {v}" for k, v in context.items() if k != "title"]
    md += ["", "## Table 5.5: accuracy, inference, training time, size", "", markdown(HEADER_55, table55_rows(rows))]
    if table56_rows(rows):
        md += ["", "## Table 5.6: whole pipeline per frame (folder frame -> labels -> grasp records)", "",
               markdown(HEADER_56, table56_rows(rows))]
    paths = {"md": out / "table.md", "csv": out / "table.csv", "json": out / "table.json", "png": out / "miou-latency.png"}
    paths["md"].write_text("\n".join(md) + "\n")
    with open(paths["csv"], "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0].to_dict()))
        writer.writeheader()
        writer.writerows(r.to_dict() for r in rows)
    paths["json"].write_text(json.dumps({"context": context, "rows": [r.to_dict() for r in rows]}, indent=1))
    plot(rows, paths["png"])
    return {k: str(v) for k, v in paths.items()}
