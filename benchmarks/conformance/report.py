"""A conformance run's report: Markdown (command, machine, versions, a summary, a table per model, the
failures, the pinned references that regressed), CSV (one row per model and engine), JSON (everything)
and a PNG of speed-up against task metric, one point per model and engine, drawn with OpenCV."""

from __future__ import annotations

import csv
import json
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np

from .engines import BASELINES
from .runner import EngineResult, ModelResult
from .spec import cpu_class

COLOURS = ((31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189), (140, 86, 75),
           (227, 119, 194), (127, 127, 127), (188, 189, 34), (23, 190, 207))  # RGB
MARKERS = (cv2.MARKER_SQUARE, cv2.MARKER_TRIANGLE_UP, cv2.MARKER_DIAMOND, cv2.MARKER_CROSS, cv2.MARKER_STAR,
           cv2.MARKER_TILTED_CROSS, cv2.MARKER_TRIANGLE_DOWN)


@dataclass(frozen=True)
class Header:
    """What a run's report says before its results: how it was run, where and with what."""

    command: str
    machine: str
    versions: dict[str, str]
    calib: int
    test: int
    runs: int
    threads: int
    date: str
    repeats: int = 1


def percent(v: float | None) -> str:
    """A share as a percentage with two decimals, '-' when there is none."""
    return "-" if v is None else f"{100 * v:.2f}"


def number(v: float | None, digits: int = 2, suffix: str = "") -> str:
    """V with DIGITS decimals and SUFFIX, '-' when there is none."""
    return "-" if v is None else f"{v:.{digits}f}{suffix}"


def speedup_text(e: EngineResult) -> str:
    """The speed-up, with its range over the repeats where it was timed more than once."""
    if e.speedup is None:
        return "-"
    low_high = f" [{e.speedup_range[0]:.2f}, {e.speedup_range[1]:.2f}]" if e.speedup_range else ""
    return f"{e.speedup:.2f}x{low_high}"


def sqnr_text(e: EngineResult) -> str:
    """The SQNR of each output in dB, in the model's order ('exact' where int8 equals fp32)."""
    return " / ".join("exact" if v is None else f"{v:.1f}" for v in e.sqnr_db.values()) or "-"


def int8_engines(results: list[ModelResult]) -> list[str]:
    """The engines of the run that quantize, in the run's order (the fp32 baselines left out)."""
    names: list[str] = []
    for m in results:
        names += [e.engine for e in m.engines if e.engine not in BASELINES.values() and e.engine not in names]
    return names


def markdown(results: list[ModelResult], header: Header, figure: str | None = None) -> str:
    versions = ", ".join(f"{k} {v}" for k, v in header.versions.items())
    engines = int8_engines(results)
    lines = [f"# Conformance: third-party float models through int8 engines, {header.threads} threads", "",
             f"Command: `{header.command}`  ", f"{header.machine}; {versions}. {header.date}.", "",
             f"Per model, {header.calib} calibration inputs (seed 0) and {header.test} other test inputs (seed 1), "
             "made and preprocessed as the model's own package does (benchmarks/conformance/); every engine "
             "quantizes the same fp32 file on the same calibration tensors. The task metric scores the package's "
             "own decision (boxes, strings, classes, masks) from each engine's outputs against fp32's on "
             "onnxruntime; 'vs truth' scores it against what the inputs were made to show, where they know it; "
             "'fp32, ±1 grey level' scores fp32 itself on the test images with every pixel moved by at most one "
             "grey level at random (a camera's own rounding): the metric's floor, below which a difference is a "
             "decision on its threshold, not the engine. "
             f"p50 over {header.runs} timed runs per engine, all engines of a model in one process in "
             "alternating blocks of 5; speed-up against fp32 on the same runtime" +
             (f"; the timing done {header.repeats} times, one after another: the median p50 and speed-up, "
              "the speed-ups' lowest and highest in brackets." if header.repeats > 1 else "."), "",
             "## Summary", "", "Task metric against fp32 (%) and speed-up, per engine:", "",
             "| " + " | ".join(["model", "family", "metric", "fp32 vs truth (%)", "fp32, ±1 grey level (%)",
                                  *engines]) + " |",
             "|---|---|---|---|---|" + "---|" * len(engines)]
    for m in results:
        by = {e.engine: e for e in m.engines}
        fp32 = by.get(BASELINES["onnxruntime"])
        cells = [("failed" if by[n].failure else f"{percent(by[n].metric)}, {speedup_text(by[n])}")
                 if n in by else "-" for n in engines]
        cells = cells if not m.failure else ["model failed: " + m.failure]
        lines.append("| " + " | ".join([m.name, m.family, m.metric, percent(fp32.truth) if fp32 else "-",
                                         percent(m.fp32_jittered), *cells]) + " |")
    if figure:
        lines += ["", f"![speed-up against task metric, one point per model and engine]({figure})"]
    lines += ["", "## Per model"]
    for m in results:
        lines += ["", f"### {m.name} ({m.family})", "",
                  f"{m.origin} ({m.licence}); input {list(m.input_shape)} {m.layout.upper()}; metric: {m.metric}; outputs "
                  f"{', '.join(m.outputs) or '-'}." + (f" {m.notes}" if m.notes else "")]
        if m.failure:
            lines += ["", f"Not run: {m.failure}"]
            continue
        lines += ["", "| engine | metric vs fp32 (%) | vs truth (%) | pinned minimum (%) | SQNR per output (dB) | "
                      "p50 (ms) | speed-up | size (MB) | quantize (s) | calibration (s) | peak memory (MB) | note |",
                  "|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for e in m.engines:
            status = f"**failed**: {e.failure}" if e.failure else e.note
            if e.regressed:
                status = "**regressed** " + status
            lines.append(f"| {e.engine} ({e.runtime}) | {percent(e.metric)} | {percent(e.truth)} | {percent(e.minimum)} | "
                         f"{sqnr_text(e)} | {number(e.p50_ms)} | {speedup_text(e)} | {number(e.size_mb)} | "
                         f"{number(e.quantize_s, 1)} | {number(e.calib_s, 1)} | {number(e.peak_mb, 0)} | {status} |")
        also = [f"{e.engine}: " + ", ".join(f"{k} {percent(v)}%" for k, v in e.also.items()) for e in m.engines if e.also]
        if also:
            lines += ["", "Also: " + "; ".join(also) + "."]
        if m.fp32_jittered is not None:
            lines += ["", f"fp32 on the test images moved by at most one grey level: {percent(m.fp32_jittered)}% "
                          "against its decisions on the images as made."]
    lines += quantize_times(results)
    failures = [(m.name, "(model)", m.failure) for m in results if m.failure]
    failures += [(m.name, e.engine, e.failure) for m in results if not m.failure for e in m.engines if e.failure]
    lines += ["", "## Failures", ""] + ([f"- {n} / {e}: {f}" for n, e, f in failures] or ["None."])
    regressed = [(m.name, e) for m in results for e in m.regressions]
    unpinned = [m.name for m in results if not m.failure and all(e.minimum is None for e in m.engines)]
    lines += ["", "## Pinned references", "",
              "Regressed (below the pinned value less its tolerance, benchmarks/conformance/models.py; the pins for "
              f"this CPU's class, {cpu_class()}):", ""]
    lines += [f"- {n} / {e.engine}: {percent(e.metric) if e.metric is not None else 'failed'} < {percent(e.minimum)}"
              for n, e in regressed] or ["None."]
    if unpinned:
        lines += ["", f"No pinned references yet: {', '.join(unpinned)}."]
    return "\n".join(lines) + "\n"


def quantize_times(results: list[ModelResult], peer: str = "ort-best") -> list[str]:
    """The markdown section comparing each int8 engine's quantize time with PEER's (onnxruntime's
    quantize_static at its best settings, pre-processing included) on the same model: per model and
    engine the ratio, and its median and range over the models (none when PEER did not run)."""
    ratios: dict[str, list[tuple[str, float]]] = {}
    for m in results:
        by = {e.engine: e for e in m.engines if not e.failure and e.quantize_s}
        if peer not in by:
            continue
        for e in by.values():
            if e.engine != peer:
                ratios.setdefault(e.engine, []).append((m.name, e.quantize_s / by[peer].quantize_s))
    if not ratios:
        return []
    lines = ["", f"## Quantize time against {peer}", "",
             f"Each engine's quantize time (the call, pre-processing included) over {peer}'s on the same model "
             "and calibration tensors, in the same process:", "", "| engine | median | lowest | highest | per model |",
             "|---|---|---|---|---|"]
    for engine, values in ratios.items():
        times = [v for _, v in values]
        per = ", ".join(f"{n} {v:.2f}x" for n, v in values)
        lines.append(f"| {engine} | {np.median(times):.2f}x | {min(times):.2f}x | {max(times):.2f}x | {per} |")
    return lines + stage_times(results, peer)


def stage_times(results: list[ModelResult], peer: str = "ort-best") -> list[str]:
    """The markdown table of where the time of each engine that reports its stages went (edgepick's
    stage_s), per model, with its calibration pass alone (stage calibrate) over PEER's whole call."""
    rows = [(m.name, e, next((p for p in m.engines if p.engine == peer and not p.failure and p.quantize_s), None))
            for m in results for e in m.engines if e.stage_s and not e.failure]
    if not rows:
        return []
    stages = list(dict.fromkeys(stage for _, e, _ in rows for stage in e.stage_s))
    lines = ["", "### Where the time went", "",
             f"Seconds per stage of each engine that reports them, and its calibration pass alone (every tensor "
             f"streamed into the histograms; with placement auto, one pass per candidate) over {peer}'s whole call; "
             "the other stages are the measurements that choose the recipe per model:", "",
             f"| model | engine | calibration pass / {peer} | " + " | ".join(stages) + " |",
             "|---|---|---|" + "---|" * len(stages)]
    passes: dict[str, list[float]] = {}
    for name, e, p in rows:
        ratio = e.stage_s.get("calibrate", 0.0) / p.quantize_s if p is not None and p.quantize_s else None
        if ratio is not None:
            passes.setdefault(e.engine, []).append(ratio)
        seconds = " | ".join(number(e.stage_s.get(stage), 1) for stage in stages)
        lines.append(f"| {name} | {e.engine} | {'-' if ratio is None else f'{ratio:.2f}x'} | {seconds} |")
    lines += ["", *(f"{engine}'s calibration pass over {peer}'s call: median {np.median(v):.2f}x, "
                    f"{min(v):.2f}x to {max(v):.2f}x over {len(v)} models." for engine, v in passes.items())]
    return lines


def write_csv(results: list[ModelResult], path: Path) -> None:
    """One row per model and engine, the lowest SQNR over the outputs."""
    fields = ["model", "family", "engine", "runtime", "metric_name", "metric", "truth", "min_sqnr_db", "p50_ms",
              "speedup", "speedup_low", "speedup_high", "size_mb", "quantize_s", "calib_s", "peak_mb", "minimum",
              "regressed", "failure", "note", "fp32_jittered"]
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(fields)
        for m in results:
            for e in m.engines:
                sqnr = [v for v in e.sqnr_db.values() if v is not None]
                w.writerow([m.name, m.family, e.engine, e.runtime, m.metric, e.metric, e.truth,
                            min(sqnr) if sqnr else "", e.p50_ms, e.speedup, *(e.speedup_range or ("", "")),
                            e.size_mb, e.quantize_s, e.calib_s, e.peak_mb, e.minimum, e.regressed, e.failure or "",
                            e.note, m.fp32_jittered])


def write_json(results: list[ModelResult], header: Header, path: Path) -> None:
    """Everything the run recorded, per output and per metric."""
    path.write_text(json.dumps({"header": asdict(header), "models": [asdict(m) for m in results]}, indent=1) + "\n")


def plot(results: list[ModelResult], path: Path, width: int = 1100, height: int = 720) -> None:
    """Speed-up (y) against task metric (x), one point per model and int8 engine, engines by colour
    and marker; points below 95% carry their model's name."""
    engines = int8_engines(results)
    points = [(m.name, e) for m in results for e in m.engines
              if e.engine in engines and e.metric is not None and e.speedup is not None]
    img = np.full((height, width, 3), 255, np.uint8)
    left, right, top, bottom = 80, 240, 50, 70
    x_lo = min([0.9] + [np.floor(e.metric * 20) / 20 for _, e in points])
    y_hi = max([2.0] + [np.ceil(e.speedup * 2) / 2 for _, e in points])

    def at(metric: float, speedup: float) -> tuple[int, int]:
        x = left + (metric - x_lo) / (1.0 - x_lo) * (width - left - right)
        y = height - bottom - speedup / y_hi * (height - top - bottom)
        return int(round(x)), int(round(y))

    font, grey, black = cv2.FONT_HERSHEY_SIMPLEX, (200, 200, 200), (0, 0, 0)
    for v in np.linspace(x_lo, 1.0, 5):
        x, _ = at(v, 0)
        cv2.line(img, (x, top), (x, height - bottom), grey, 1)
        cv2.putText(img, f"{100 * v:.1f}", (x - 20, height - bottom + 20), font, 0.45, black, 1, cv2.LINE_AA)
    for v in np.arange(0, y_hi + 1e-9, 0.5):
        _, y = at(x_lo, v)
        cv2.line(img, (left, y), (width - right, y), (120, 120, 120) if v == 1.0 else grey, 1)
        cv2.putText(img, f"{v:.1f}x", (left - 50, y + 5), font, 0.45, black, 1, cv2.LINE_AA)
    cv2.rectangle(img, (left, top), (width - right, height - bottom), black, 1)
    cv2.putText(img, "task metric against fp32 (%)", (left + 250, height - 25), font, 0.55, black, 1, cv2.LINE_AA)
    cv2.putText(img, "speed-up against fp32 on the same runtime", (left, top - 20), font, 0.55, black, 1, cv2.LINE_AA)
    style = {name: (COLOURS[k % len(COLOURS)][::-1], MARKERS[k % len(MARKERS)]) for k, name in enumerate(engines)}
    for name, e in points:
        colour, marker = style[e.engine]
        x, y = at(e.metric, e.speedup)
        cv2.drawMarker(img, (x, y), colour, marker, 14, 2, cv2.LINE_AA)
        if e.metric < 0.95:
            cv2.putText(img, name, (x + 8, y - 6), font, 0.35, colour, 1, cv2.LINE_AA)
    for k, name in enumerate(engines):
        colour, marker = style[name]
        y = top + 20 + 26 * k
        cv2.drawMarker(img, (width - right + 25, y), colour, marker, 14, 2, cv2.LINE_AA)
        cv2.putText(img, name, (width - right + 42, y + 5), font, 0.5, black, 1, cv2.LINE_AA)
    cv2.imwrite(str(path), img)


def write(results: list[ModelResult], header: Header, md: Path) -> list[Path]:
    """The four files beside MD (its .csv, .json, .png); returns them."""
    md.parent.mkdir(parents=True, exist_ok=True)
    md.write_text(markdown(results, header, md.with_suffix(".png").name))
    write_csv(results, md.with_suffix(".csv"))
    write_json(results, header, md.with_suffix(".json"))
    plot(results, md.with_suffix(".png"))
    return [md, md.with_suffix(".csv"), md.with_suffix(".json"), md.with_suffix(".png")]
