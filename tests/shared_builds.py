"""The session's shared builds (a synthetic data set, a short training run, its ONNX exports): each
built once into one folder for all pytest-xdist workers, under a file lock, and read only after.

`tests/conftest.py` starts `python -m tests.shared_builds ROOT` in the background when the first
worker begins a session that has tests needing the run: the run then trains beside the tests that
need none, instead of a worker waiting for it. Whoever takes a build's lock first builds it; the
others wait on the lock and find it whole (a `.done` file beside it). A build that failed in the
background is built again by the first test that needs it, which then shows the error."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

from filelock import FileLock

REPO = Path(__file__).resolve().parents[1]
EPOCHS = 25  # the shared run's epochs: ~100 s on one core


def run_cli(*args: str, check: bool = False, timeout: float = 600, env: dict | None = None) -> subprocess.CompletedProcess:
    """Run `python -m edgepick ARGS` in a subprocess, as a user would."""
    proc = subprocess.run([sys.executable, "-m", "edgepick", *args], capture_output=True, text=True, timeout=timeout,
                          cwd=REPO, env={**os.environ, **(env or {})})
    if check and proc.returncode != 0:
        raise AssertionError(f"edgepick {' '.join(args)} exited {proc.returncode}\n{proc.stderr[-3000:]}")
    return proc


def shared_at(root: Path, name: str, make: Callable[[Path], None]) -> Path:
    """The folder ROOT/shared/NAME that MAKE(folder) builds, once: the first process to take its lock
    builds it while the others wait (a run records its own folder, so it is built where it stays)."""
    out = root / "shared" / name
    out.parent.mkdir(exist_ok=True)
    done = out.with_name(name + ".done")
    with FileLock(str(out) + ".lock"):
        if not done.exists():
            shutil.rmtree(out, ignore_errors=True)
            make(out)
            done.touch()
    return out


def synth_data(root: Path) -> Path:
    """48 scenes at 320x240 (train 36 / val 8 / test 4)."""
    from edgepick.data.synth import SynthConfig, synthesize

    def make(out: Path) -> None:
        synthesize(out, SynthConfig(scenes=48, width=320, height=240, seed=7, splits=(36, 8, 4)), progress=False)
    return shared_at(root, "synth", make)


def short_run(root: Path) -> Path:
    """A short CPU training run (MobileNetV3, 128x96) on synth_data, on one thread (beside the workers)."""
    from edgepick.geometry import Size
    from edgepick.train.loop import TrainConfig, train

    data = synth_data(root)

    def make(out: Path) -> None:
        train(TrainConfig(data=str(data), out=str(out), epochs=EPOCHS, batch_size=4, size=Size(128, 96),
                          device="cpu", lr=2e-3, keep_epochs=[2, EPOCHS - 1]), progress=False)
    return shared_at(root, "run", make)


def run_exports(root: Path) -> Path:
    """short_run exported by the CLI as a user would: `edgepick export` (fp32.onnx) and `edgepick
    quantize static` on 16 calibration images (static.onnx), each command's JSON beside its file."""
    data, run = synth_data(root), short_run(root)

    def make(out: Path) -> None:
        out.mkdir(parents=True)
        fp32 = run_cli("export", str(run), "--out", str(out / "fp32.onnx"), check=True).stdout
        static = run_cli("quantize", "static", str(run), "--data", str(data), "--out", str(out / "static.onnx"),
                         "--calib-images", "16", check=True).stdout
        for name, text in (("fp32", fp32), ("static", static)):
            json.loads(text)  # whole, or the build fails
            (out / f"{name}.json").write_text(text)
    return shared_at(root, "onnx", make)


def start_in_background(root: Path) -> subprocess.Popen:
    """Build everything above under ROOT in a process of its own, one thread, output to ROOT/shared/build.log."""
    (root / "shared").mkdir(parents=True, exist_ok=True)
    with (root / "shared" / "build.log").open("w") as log:  # the child holds its own copy of the file
        return subprocess.Popen([sys.executable, "-m", "tests.shared_builds", str(root)], cwd=REPO, stdout=log,
                                stderr=subprocess.STDOUT, env={**os.environ, "OMP_NUM_THREADS": "1"})


if __name__ == "__main__":
    run_exports(Path(sys.argv[1]))
