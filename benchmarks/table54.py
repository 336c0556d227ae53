"""Thesis Table 5.4 for today: every model family trained with one recipe and the same seeds,
quantized (static PTQ and hybrid-QaT 5%) and judged on what an edge deployment needs.

    python benchmarks/table54.py --quick              # 2-core CPU, about an hour: 96x72 runs of 6 families
    python benchmarks/table54.py --setting gpu        # the thesis's scale: 640x480, 100 epochs, all 9 (one GPU)
    python benchmarks/table54.py --setting smoke      # the script's plumbing in minutes; its figures mean nothing

Per architecture: parameters and GFLOPs at 640x480; fp32 test mIoU and pixel accuracy as mean and
range over the seeds; the test mIoU drop of static int8 and of hybrid-QaT 5% (mean over the
seeds); fp32 and int8 p50 at 640x480 on 2 threads on onnxruntime and OpenVINO (seed 0's weights
exported at 640x480, the four timed in turn in one process, in blocks of up to 5); the int8 file's size;
grasp success over CELL executions in the synthetic cell (seed 0's int8 file at its training size,
the same cycles for every architecture). --work DIR keeps the runs, and a rerun resumes after the
last finished step. Writes benchmarks/results/table54/<date>-<machine>-<setting>.md and .png.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import sys
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from _common import RESULTS, interleaved_times, machine_line  # noqa: E402

from edgepick.bench.cell import run_cell  # noqa: E402
from edgepick.bench.report import draw_axes, markdown  # noqa: E402
from edgepick.data.synth import SynthConfig, synthesize  # noqa: E402
from edgepick.evaluation import evaluate  # noqa: E402
from edgepick.export.onnx_export import export_checkpoint  # noqa: E402
from edgepick.geometry import Size  # noqa: E402
from edgepick.machine import machine_slug, results_file  # noqa: E402
from edgepick.models.config import Arch  # noqa: E402
from edgepick.quant.config import DEFAULT_CALIB_IMAGES  # noqa: E402
from edgepick.quant.pt2e.images import folder_images, run_images  # noqa: E402
from edgepick.quant.pt2e.passes import quantize_hybrid, quantize_static  # noqa: E402
from edgepick.runtime.engine import Engine  # noqa: E402
from edgepick.runtime.session import Segmenter  # noqa: E402
from edgepick.train.checkpoint import Checkpoint  # noqa: E402
from edgepick.train.loop import TrainConfig, train  # noqa: E402

THESIS = ("segnet", "fcn-resnet101", "unet", "deeplabv3-mobilenetv3")  # Table 5.4's four, in its order
FRAME = Size(640, 480)
QAT_FRACTION = 0.05


@dataclass(frozen=True)
class Setting:
    """A scale of the study. Hybrid-QaT 5% needs 11 epochs or more: 5% of fewer rounds to none."""

    name: str
    archs: tuple[str, ...]
    splits: tuple[int, int, int]  # train, val, test scenes
    data_size: Size
    size: Size  # the models' input while training
    epochs: int
    batch: int
    seeds: tuple[int, ...]
    cell: int  # cell executions per architecture
    runs: int  # timed inferences per file at 640x480
    device: str = "auto"
    epoch_images: int = 0  # 0: an epoch is the whole train split; N: N train images drawn afresh per epoch
    val_images: int = 0  # 0: validate on the whole val split each epoch; N: on N of its images
    frame_calib: int = 64  # calibration images of the 640x480 files that are only timed
    warmup: int = 3  # untimed inferences per file before the timed ones


SETTINGS = {s.name: s for s in (
    Setting("smoke", ("lraspp-mobilenetv3", "ddrnet23-slim"), (12, 4, 4), Size(128, 96), Size(64, 48), 11, 4, (0, 1),
            4, 3, "cpu"),
    # about an hour of 2 cores (the result file gives the sum of the steps' times): at 96x72 a batch
    # of 8 costs SegNet, U-Net and FCN-ResNet101 about 2 s, the MobileNet and DDRNet models 0.2-0.4 s;
    # each run's export and int8 passes add 1-3 min (about half of the whole), and timing the big
    # three at 640x480 2-6 min each, which leaves training 12 epochs of 32 images
    Setting("quick", ("segnet", "fcn-resnet101", "unet", "deeplabv3-mobilenetv3", "lraspp-mobilenetv3",
                      "ddrnet23-slim"), (240, 32, 32), Size(192, 144), Size(96, 72), 12, 8, (0, 1, 2), 50, 5, "cpu",
            epoch_images=32, val_images=16, frame_calib=8, warmup=1),
    Setting("gpu", tuple(a.value for a in Arch), (4000, 1000, 100), FRAME, FRAME, 100, 16, (0, 1, 2), 50, 20, "cuda"),
)}


def step(path: Path, make) -> dict:
    """The JSON record at PATH, made by MAKE() the first time (a rerun of the script resumes), with
    the seconds it took as "step_s"."""
    if not path.is_file():
        started = time.monotonic()
        record = make()
        tmp = path.with_suffix(".partial")
        tmp.write_text(json.dumps({**record, "step_s": round(time.monotonic() - started, 2)}))
        os.replace(tmp, path)
    return json.loads(path.read_text())


def claim_work(work: Path, s: Setting) -> None:
    """Make WORK this script's folder for setting S, or exit with one line: a folder it did not make
    (nothing of it is removed) or one that holds another setting's steps is refused."""
    marker = work / "table54.json"
    if marker.is_file():
        held = json.loads(marker.read_text())["setting"]
        if held != s.name:
            sys.exit(f"table54: error: --work {work} holds the {held} setting's steps, not {s.name}'s")
    elif work.is_dir() and any(work.iterdir()):
        sys.exit(f"table54: error: --work {work} is a folder this script did not make; name a new or empty one")
    work.mkdir(parents=True, exist_ok=True)
    marker.write_text(json.dumps({"setting": s.name}))


def train_and_quantize(work: Path, s: Setting, arch: str, seed: int, data: Path, echo) -> dict:
    """One run: float training, static int8, hybrid-QaT 5%; each scored on the test split."""
    here = work / arch / f"seed{seed}"
    here.mkdir(parents=True, exist_ok=True)
    switch = round((1 - QAT_FRACTION) * s.epochs)

    def float_run() -> dict:
        echo(f"table54: train {arch} seed {seed}")
        shutil.rmtree(here / "run", ignore_errors=True)
        result = train(TrainConfig(data=str(data), out=str(here / "run"), arch=arch, epochs=s.epochs,
                                   batch_size=s.batch, size=s.size, lr=2e-3, device=s.device, seed=seed,
                                   keep_epochs=(switch,), epoch_images=s.epoch_images,
                                   val_images=s.val_images), progress=False)
        return {"train_s": result.train_time_s}

    def scored(make_file) -> dict:
        record = make_file()
        score = evaluate(record["out"], data, "test", progress=False)
        return {**record, "miou": score["miou"], "pixel_acc": score["pixel_acc"]}

    out = {"float": step(here / "float.json", float_run)}
    out["fp32"] = step(here / "fp32.json", lambda: scored(
        lambda: export_checkpoint(here / "run", here / "fp32.onnx").to_dict()))
    out["static"] = step(here / "static.json", lambda: scored(
        lambda: quantize_static(here / "run", folder_images(data), here / "static.onnx", progress=False).to_dict()))
    out["hybrid"] = step(here / "hybrid.json", lambda: scored(
        lambda: quantize_hybrid(here / "run", data, here / "hybrid.onnx", QAT_FRACTION, run_images(here / "run", data),
                                qat_run=here / "qat",
                                progress=False, device=s.device).to_dict()))
    return out


def size_and_speed(work: Path, s: Setting, arch: str, data: Path, echo) -> dict:
    """Parameters, GFLOPs, and fp32/int8 p50 at 640x480 on both engines, of seed 0's weights."""
    import torch
    from torch.utils.flop_counter import FlopCounterMode

    here = work / arch / "frame"
    here.mkdir(parents=True, exist_ok=True)
    echo(f"table54: {arch} at {FRAME}")
    ckpt = Checkpoint.load(work / arch / f"seed{s.seeds[0]}" / "run")  # its best epoch
    big = replace(ckpt, input_size=FRAME)
    big.save(here / "frame.pt")
    model = big.build_model().eval()
    params = sum(p.numel() for p in model.parameters())
    with torch.no_grad(), FlopCounterMode(display=False) as flops:
        model(torch.zeros(1, 3, *FRAME.hw))
    files = {"fp32": export_checkpoint(here / "frame.pt", here / "fp32.onnx").out,
             "int8": quantize_static(here / "frame.pt", folder_images(data, count=min(s.frame_calib, s.splits[0])),
                                     here / "int8.onnx", progress=False).out}
    rgb = cv2.resize(folder_images(data, "test", count=1)[0], (FRAME.width, FRAME.height))
    timed, names = [], []
    for engine in (Engine.ONNXRUNTIME, Engine.OPENVINO):
        for precision, path in files.items():
            seg = Segmenter(path, threads=2, engine=engine)
            image = seg.prepare(rgb)
            for _ in range(s.warmup):
                seg.infer(image)
            timed.append(lambda i, seg=seg, image=image: seg.infer(image))
            names.append(f"{precision} {engine}")
    times = interleaved_times(timed, s.runs)
    return {"params_m": params / 1e6, "gflops": flops.get_total_flops() / 1e9,
            "int8_mb": Path(files["int8"]).stat().st_size / 1e6,
            "p50_ms": {n: float(np.median(t)) for n, t in zip(names, times)}}


def plot(rows: list[dict], path: Path) -> None:
    """Grasp success against the int8 p50 on onnxruntime at 640x480 (a log axis: the families span
    tens of milliseconds to seconds), one labelled point per architecture."""
    img = np.full((520, 800, 3), 255, np.uint8)
    xs = [float(np.log10(r["speed"]["p50_ms"]["int8 onnxruntime"])) for r in rows]
    ticks = [v for v in (1, 3, 10, 30, 100, 300, 1000, 3000, 10000, 30000) if min(xs) - 0.3 <= np.log10(v) <= max(xs) + 0.3]
    lo, hi = min(xs) - 0.3, max(xs) + 0.3
    px = draw_axes(img, (80, 770, 40, 460), (lo, hi), (0.0, 100.0), [float(np.log10(v)) for v in ticks],
                   [0.0, 25.0, 50.0, 75.0, 100.0], ("", "{:.0f}"),
                   ("int8 p50 at 640x480, onnxruntime, 2 threads (ms, log scale)", "grasp success (%)"))
    for v in ticks:
        cv2.putText(img, f"{v}", (px(float(np.log10(v)), 0.0)[0] - 12, 480), cv2.FONT_HERSHEY_SIMPLEX, 0.45,
                    (0, 0, 0), 1)
    placed: list[tuple[int, int]] = []
    for r, x in zip(rows, xs):
        p = px(x, 100 * r["cell"])
        near = sum(abs(p[0] - q[0]) < 90 and abs(p[1] - q[1]) < 20 for q in placed)  # stack crowded labels
        placed.append(p)
        cv2.circle(img, p, 5, (200, 60, 20), -1)
        cv2.putText(img, r["arch"], (p[0] + 7, p[1] - 7 - 16 * near), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1,
                    cv2.LINE_AA)
    cv2.imwrite(str(path), img)


def spread(values: list[float]) -> str:
    mean = 100 * statistics.fmean(values)
    return f"{mean:.2f} ({100 * min(values):.2f}-{100 * max(values):.2f})" if len(values) > 1 else f"{mean:.2f}"


def report(s: Setting, rows: list[dict], command: str, truth: float, png: str, minutes: float) -> str:
    head = ["Architecture", "Params (M)", "GFLOPs 640x480", "fp32 mIoU (%)", "fp32 pixel acc (%)",
            "static drop (pp)", "hybrid 5% drop (pp)", "fp32 / int8 p50 ORT (ms)", "fp32 / int8 p50 OV (ms)",
            "int8 size (MB)", f"grasp success, {s.cell} (%)"]
    body = []
    for r in rows:
        fp32 = [x["fp32"]["miou"] for x in r["seeds"]]
        drop = {m: 100 * statistics.fmean(x["fp32"]["miou"] - x[m]["miou"] for x in r["seeds"]) for m in ("static", "hybrid")}
        p = r["speed"]["p50_ms"]
        body.append([r["arch"], f"{r['speed']['params_m']:.2f}", f"{r['speed']['gflops']:.1f}", spread(fp32),
                     spread([x["fp32"]["pixel_acc"] for x in r["seeds"]]), f"{drop['static']:+.2f}",
                     f"{drop['hybrid']:+.2f}", f"{p['fp32 onnxruntime']:.1f} / {p['int8 onnxruntime']:.1f}",
                     f"{p['fp32 openvino']:.1f} / {p['int8 openvino']:.1f}", f"{r['speed']['int8_mb']:.2f}",
                     f"{100 * r['cell']:.0f}"])
    epoch = f" of {s.epoch_images} train images drawn afresh" if s.epoch_images else ""
    calib = min(s.frame_calib, s.splits[0])
    static_calib = min(DEFAULT_CALIB_IMAGES, s.splits[0])  # quantize_static's default over the train split
    return (f"# Table 5.4 extended ({s.name} setting)\n\nCommand: `{command}`\n\n{machine_line()}\n\n"
            f"Time: {minutes:.0f} min, the sum of every step's (data set, training, passes, timing, cell): "
            "the same whether the steps ran in one go or were resumed from --work.\n\n"
            f"- data: `edgepick data synth` of {sum(s.splits)} scenes at {s.data_size} (train/val/test "
            f"{'/'.join(map(str, s.splits))}, seed 11); every run {s.epochs} epochs{epoch} at {s.size}, batch {s.batch}, "
            f"AdamW lr 2e-3, seeds {', '.join(map(str, s.seeds))}; the thesis trained each for 100 epochs at 640x480\n"
            "- GFLOPs: floating-point operations of one 640x480 inference, a multiply-add counting 2 (torch's "
            "FlopCounterMode)\n"
            "- mIoU and pixel accuracy: the test split, mean over the seeds and their range; a difference inside "
            "the range is not a result\n"
            f"- drops: fp32 minus int8 test mIoU, mean over the seeds (static: percentile, {static_calib} images; "
            "hybrid: the "
            f"last {QAT_FRACTION:.0%} of the epochs QaT)\n"
            f"- p50: seed 0's weights exported at 640x480 (static int8 calibrated on {calib} train images), 2 threads, "
            f"{s.runs} timed runs each, the four files taken in turn in blocks of up to 5, each after an untimed call\n"
            f"- grasp success: seed 0's static int8 file in the synthetic cell (seed 0 scenes), {s.cell} "
            f"executions; the scenes' true labels: {100 * truth:.0f}%\n\n"
            + markdown(head, body) + f"\n\n![success against latency]({png})\n")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--setting", default="quick", choices=sorted(SETTINGS))
    ap.add_argument("--quick", action="store_true", help="same as --setting quick")
    ap.add_argument("--work", default=None, help="work folder, kept and resumed (default: a fresh one, removed)")
    ap.add_argument("--out", default=None, help="write the report here instead of benchmarks/results/table54/")
    args = ap.parse_args()
    s = SETTINGS["quick" if args.quick else args.setting]
    work = Path(args.work or tempfile.mkdtemp(prefix="table54-"))
    claim_work(work, s)
    echo = lambda line: print(line, file=sys.stderr, flush=True)  # noqa: E731
    data = work / "data"

    def synth() -> dict:
        echo(f"table54: synthetic data, {sum(s.splits)} scenes")
        shutil.rmtree(data, ignore_errors=True)
        synthesize(data, SynthConfig(scenes=sum(s.splits), width=s.data_size.width, height=s.data_size.height,
                                     seed=11, splits=s.splits), progress=False)
        return {"scenes": sum(s.splits)}

    steps = [step(work / "data.json", synth)]
    rows = []
    for arch in s.archs:
        seeds = [train_and_quantize(work, s, arch, seed, data, echo) for seed in s.seeds]
        speed = step(work / arch / "speed.json", lambda arch=arch: size_and_speed(work, s, arch, data, echo))
        rows.append({"arch": arch, "seeds": seeds, "speed": speed})
        steps += [speed, *(record for seed in seeds for record in seed.values())]

    def cell_rates() -> dict:
        echo(f"table54: the cell, {s.cell} executions per architecture")
        files = [str(work / r["arch"] / f"seed{s.seeds[0]}" / "static.onnx") for r in rows]
        return {"rates": [c["success_rate"] for c in run_cell(files, s.cell, work / "cell", progress=echo)["rows"]]}

    cell = step(work / "cell.step.json", cell_rates)
    steps.append(cell)
    for r, rate in zip(rows, cell["rates"][1:]):
        r["cell"] = rate
    command = f"python benchmarks/table54.py --setting {s.name}"
    md = Path(args.out) if args.out else results_file(RESULTS, "table54", f"{machine_slug()}-{s.name}")
    md.parent.mkdir(parents=True, exist_ok=True)
    plot(rows, md.with_suffix(".png"))
    minutes = sum(record["step_s"] for record in steps) / 60
    md.write_text(report(s, rows, command, cell["rates"][0], md.with_suffix(".png").name, minutes))
    print(md.read_text())
    if not args.work:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
