"""Thesis Tables 5.5 and 5.6, regenerated in one go: synthetic data, one float run, static PTQ,
QaT from scratch, hybrid-QaT 1/5/10% from the float run's kept epochs, then the bench.

`benchmarks/table55.py` writes the result under benchmarks/results/; `make demo` runs it, step by
step, at the quick setting.
"""

from __future__ import annotations

import json
import os
import platform
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

from edgepick.bench.measure import BenchConfig
from edgepick.bench.run import run_bench
from edgepick.files import atomic_write
from edgepick.geometry import Size
from edgepick.machine import machine_line, machine_slug
from edgepick.schema import member


@dataclass(frozen=True)
class Setting:
    """The scale of one table run."""

    name: str
    splits: tuple[int, int, int]  # synthetic train/val/test scenes (640x480)
    size: Size  # the model's training input
    epochs: int  # the epoch budget E; hybrid-QaT switches at (1 - p)E, so E = 100 gives 1/5/10% exactly
    batch_size: int
    lr: float
    runs: int  # timed inferences per model
    epoch_images: int = 0  # images per epoch drawn from the train split (0: the whole split)
    val_images: int = 0  # val images scored after each epoch (0: the whole split)

    def describe(self) -> str:
        per_epoch = f"{self.epoch_images} images drawn afresh from the train split" if self.epoch_images else "the whole train split"
        val = f"{self.val_images} of the val images" if self.val_images else "the whole val split"
        return (f"synthetic splits {self.splits} at 640x480, model input {self.size}, "
                f"{self.epochs} epochs of {per_epoch} (validated on {val}), batch {self.batch_size}, lr {self.lr}")


# Scaled down until the whole table takes minutes on 2 CPU cores: 3 steps per epoch at 96x64.
QUICK = Setting("quick", splits=(24, 12, 12), size=Size(96, 64), epochs=100, batch_size=8, lr=2e-3, runs=30)
# The thesis's data scale on a short GPU budget: the 4000/1000/100 split at 640x480 and E = 100 epochs
# (so 1/5/10% are whole epochs), each epoch 160 images drawn from the train split (4 passes over it in all).
SHORT = Setting("short", splits=(4000, 1000, 100), size=Size(640, 480), epochs=100, batch_size=16, lr=2e-3, runs=50,
                epoch_images=160, val_images=100)
FULL = Setting("full", splits=(4000, 1000, 100), size=Size(640, 480), epochs=100, batch_size=16, lr=1e-3, runs=100)
SETTINGS = {s.name: s for s in (QUICK, SHORT, FULL)}
FRACTIONS = (0.01, 0.05, 0.10)
PHASES = ("synth", "float", "fp32", "static", "qat", "hybrid", *(f"hybrid{p:.2f}" for p in FRACTIONS), "bench")


def _record(work: Path, update) -> dict:
    """Read-modify-write WORK/phases.json under a lock (phases may run in parallel processes)."""
    import fcntl

    lock = os.open(work, os.O_RDONLY)  # the folder itself is the lock: no lock file left behind
    try:
        fcntl.flock(lock, fcntl.LOCK_EX)
        path = work / "phases.json"
        state = json.loads(path.read_text()) if path.is_file() else {"times": {}, "commands": []}
        update(state)
        atomic_write(path, json.dumps(state, indent=1))
        return state
    finally:
        os.close(lock)


def make_table55(work: str | Path, setting: Setting, device: str = "auto", command: str = "",
                 echo=print, only: set[str] | None = None) -> dict | None:
    """Run the phases in WORK and return the Markdown report, the PNG's path, the phase wall
    times and the bench rows. A phase whose output is already in WORK is kept (its time comes
    from WORK/phases.json), so the phases can be split over several runs or machines; ONLY
    limits this run to some PHASES (then no report unless the bench ran). The phases read top to
    bottom in _run_phases, in the order they run, as the table's recipe."""
    import onnxruntime  # noqa: F401 - the [train] extra's absence is said before WORK is made
    import torch  # noqa: F401
    import torchao  # noqa: F401

    work = Path(work)
    work.mkdir(parents=True, exist_ok=True)
    if command:
        _record(work, lambda st: st["commands"].append(command))
    files = _run_phases(_Phases(work, echo, only), setting, device)
    if (only is not None and "bench" not in only) or not all(f.exists() for f in files):
        return None
    t0 = time.perf_counter()
    echo("-- bench")
    bench = run_bench(files, work / "data", work / "bench", BenchConfig(threads=2, runs=setting.runs),
                      gpu_checkpoint=work / "float", title="Table 5.5 / 5.6", progress=lambda line: None)
    state = _record(work, lambda st: st["times"].update({"bench": round(time.perf_counter() - t0, 1)}))
    return _report(setting, device, state, bench)


@dataclass(frozen=True)
class _Phases:
    """Where the phases run (WORK), how each says it starts (ECHO), and which of them this run does
    (ONLY; None: all)."""

    work: Path
    echo: Callable[[str], object]
    only: set[str] | None

    def run(self, name: str, phase: str, output: Path, fn: Callable, *a, **k) -> None:
        """Run phase PHASE (NAME in the tables) unless its OUTPUT exists or ONLY leaves it out; its wall
        time (and an int8 pass's agreement with torch) goes into WORK/phases.json."""
        work, only = self.work, self.only
        if output.exists() or (only is not None and phase not in only and phase.rstrip("0123456789.") not in only):
            return
        for stale in {"float": [work / "float"], "qat": [work / "qat"]}.get(phase, []) + (
                [Path(k["qat_run"])] if "qat_run" in k else []):
            shutil.rmtree(stale, ignore_errors=True)  # a run cut off earlier: start it again
        self.echo(f"-- {name}")
        t0 = time.perf_counter()
        result = fn(*a, **k)
        seconds = round(time.perf_counter() - t0, 1)
        agreement = getattr(result, "agreement_vs_torch", None)  # int8 passes only

        def update(st: dict) -> None:
            st["times"][name] = seconds
            if agreement is not None:  # int8 passes: onnxruntime labels against torch's simulation
                st.setdefault("agreement", {})[name] = agreement
        _record(work, update)


def _run_phases(phases: _Phases, s: Setting, device: str) -> list[Path]:
    """The table's recipe, phase by phase: synthetic data, the float run (keeping the hybrid-QaT switch
    epochs), its fp32 export, static PTQ, QaT from scratch, hybrid-QaT at each fraction. Returns the
    model files the bench compares."""
    from edgepick.data.synth import SynthConfig, synthesize
    from edgepick.export.onnx_export import export_checkpoint
    from edgepick.quant import agreement_images, folder_images, quantize_hybrid, quantize_qat, quantize_static, run_images
    from edgepick.train.config import Device
    from edgepick.train.loop import TrainConfig, train

    work = phases.work
    data = work / "data"
    phases.run("synth", "synth", data / "meta.json", synthesize, data,
               SynthConfig(scenes=sum(s.splits), splits=s.splits, seed=0), progress=False)
    tc = TrainConfig(data=str(data), out=str(work / "float"), epochs=s.epochs, batch_size=s.batch_size, size=s.size,
                     lr=s.lr, device=member(Device, "device", device), keep_epochs=tuple(_kept_epochs(s)),
                     epoch_images=s.epoch_images, val_images=s.val_images)
    phases.run("float training", "float", work / "float" / "done", _train_and_mark, train, tc)
    files = list(model_files(work).values())
    phases.run("fp32 export", "fp32", files[0], export_checkpoint, work / "float", files[0])
    phases.run("static PTQ", "static", files[1], lambda: quantize_static(
        work / "float", folder_images(data, "train", min(64, s.splits[0])), files[1],
        check_images=agreement_images(data), progress=False))
    qat_tc = replace(tc, out=str(work / "qat"), keep_epochs=())
    phases.run("QaT from scratch", "qat", files[2], quantize_qat, qat_tc, files[2], progress=False)
    for p, f in zip(FRACTIONS, files[3:]):
        phases.run(f"hybrid-QaT {p:.0%}", f"hybrid{p:.2f}", f, lambda f=f, p=p, **k: quantize_hybrid(
            work / "float", data, f, p, run_images(work / "float", data), device=member(Device, "device", device),
            progress=False, **k), qat_run=work / f"hybrid{p:.2f}.run")
    return files


def model_files(work: Path) -> dict[str, Path]:
    """The model file each phase writes in WORK, by the phase's name in the tables (phases.json),
    in the order the bench compares them."""
    models = work / "models"
    return {"fp32 export": models / "fp32.onnx", "static PTQ": models / "static.onnx",
            "QaT from scratch": models / "qat.onnx",
            **{f"hybrid-QaT {p:.0%}": models / f"hybrid{p:.2f}.onnx" for p in FRACTIONS}}


def _kept_epochs(s: Setting) -> list[int]:
    """The float run's epochs that hybrid-QaT at each of FRACTIONS starts from."""
    return sorted({round((1 - p) * s.epochs) for p in FRACTIONS})


def _report(s: Setting, device: str, state: dict, bench: dict) -> dict:
    """make_table55's result: the Markdown report (the machine, versions, setting, phase times and
    agreement, then the bench's Table 5.5 / 5.6), the PNG's path, the phase times and the bench rows."""
    import onnxruntime
    import torch
    import torchao

    phases = state["times"]
    keep = _kept_epochs(s)
    gpu = torch.cuda.is_available() and device != "cpu"
    gpu_name = torch.cuda.get_device_name() if torch.cuda.is_available() else None
    name = machine_slug(gpu_name) + ("" if s is FULL else f"-{s.name}")
    table = Path(bench["reports"]["md"]).read_text().split("## Table 5.5", 1)[1]
    commands = " && ".join(f"`{c}`" for c in dict.fromkeys(state["commands"]))
    lines = [f"# Thesis Table 5.5 / 5.6 on {name}", "",
             f"Command: {commands} (every figure below comes from this work folder's phases)", "",
             f"- {machine_line(gpu_name)}",
             f"- versions: python {platform.python_version()}, torch {torch.__version__}, torchao {torchao.__version__}, "
             f"onnxruntime {onnxruntime.__version__}",
             f"- setting: {'QUICK (scaled down for a 2-core CPU: not the thesis scale)' if s is QUICK else s.name}; "
             f"{s.describe()}; device {'cuda' if gpu else 'cpu'}; hybrid-QaT from the float run's "
             f"epochs {keep} (p = 10/5/1%); inference on 2 onnxruntime threads, {s.runs} timed runs per model",
             f"- phase wall times (s): {json.dumps(phases)}",
             *([f"- onnxruntime-vs-torch label agreement of the int8 files (8 val images): "
                f"{json.dumps(state['agreement'])}"] if state.get("agreement") else []),
             *([f"- {n}" for n in bench["notes"]]), "", "## Table 5.5" + table]
    return {"name": name, "markdown": "\n".join(lines), "png": bench["reports"]["png"], "phases": phases,
            "rows": bench["rows"]}


def _train_and_mark(train, tc) -> None:
    """Train, then mark the run complete (an interrupted run is started again, not kept)."""
    train(tc, progress=False)
    (Path(tc.out) / "done").write_text("")
