"""Shared fixtures: one small synthetic data set and one short training run per test session.

`make test` runs the suite on two pytest-xdist workers: most of a quantization test's time is
single-threaded Python (torch.export, pattern matching), so one worker alone leaves a 2-core machine
half idle. Each test file runs on one worker (`--dist loadfile`), so a module fixture is built
once (`--dist loadgroup` would be finer, but with pytest 9.2 xdist 3.8 ignores its groups:
pytest-dev/pytest-xdist#1386). The session fixtures are built once for all workers (under a file
lock) and read only."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

import pytest
from filelock import FileLock

from edgepick.runtime.grasp_record import NO_DEPTH, Grasp

# one thread per xdist worker: two workers with two OpenMP threads each would run four threads on 2 cores
os.environ.setdefault("OMP_NUM_THREADS", "1" if "PYTEST_XDIST_WORKER" in os.environ else "2")
REPO = Path(__file__).resolve().parents[1]
EPOCHS = 25  # ~100 s on 2 cores


TRAINED = {"trained_run", "onnx_files"}  # fixtures built on a training run: `make check` leaves their tests out


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Mark every test that needs the session's training run `trained` (`-m "not trained"` skips them)."""
    for item in items:
        if TRAINED & set(getattr(item, "fixturenames", ())):
            item.add_marker(pytest.mark.trained)


def run_cli(*args: str, check: bool = False, timeout: float = 600, env: dict | None = None) -> subprocess.CompletedProcess:
    """Run `python -m edgepick ARGS` in a subprocess, as a user would."""
    proc = subprocess.run([sys.executable, "-m", "edgepick", *args], capture_output=True, text=True, timeout=timeout,
                          cwd=REPO, env={**os.environ, **(env or {})})
    if check and proc.returncode != 0:
        raise AssertionError(f"edgepick {' '.join(args)} exited {proc.returncode}\n{proc.stderr[-3000:]}")
    return proc


def without_torch(folder: Path) -> dict:
    """The environment of a subprocess in which `import torch` fails (a stand-in package under
    FOLDER comes first on its path): for the mistakes a command must report before loading torch."""
    blocked = folder / "torch"
    blocked.mkdir(parents=True, exist_ok=True)
    (blocked / "__init__.py").write_text("raise ImportError('torch is not imported before a mistake is found')\n")
    return {"PYTHONPATH": str(folder)}


def make_grasp(cls: str, pose_robot: Sequence[float] | None, **fields) -> Grasp:
    """A Grasp for the tests that choose, plan or judge one: CLS at POSE_ROBOT (None: not posed), the
    rest as FIELDS give it, else seen at the image's centre, 0.62 m away, over 900 pixels."""
    depth = fields.pop("depth_m", 0.62)
    seen = {"pixel": (320.0, 240.0), "angle_deg": 0.0, "orientation_defined": True, "area_px": 900, "depth_m": depth,
            "point_camera_m": None if depth is None else (0.0, 0.0, depth), "reason": NO_DEPTH if depth is None else None}
    return Grasp(cls, pose_robot=None if pose_robot is None else tuple(pose_robot), **{**seen, **fields})


def worker_index() -> int:
    """This pytest-xdist worker's number (gw0 -> 0), 0 without xdist."""
    return int(os.environ.get("PYTEST_XDIST_WORKER", "gw0").removeprefix("gw") or 0)


def shared(tmp_path_factory: pytest.TempPathFactory, name: str, make: Callable[[Path], None]) -> Path:
    """The folder NAME that MAKE(folder) builds, once for all xdist workers of this session: the
    first worker to ask builds it while the others wait on the lock; a `.done` file beside it says
    it is whole (a run records its own folder, so it is built where it stays)."""
    root = tmp_path_factory.getbasetemp()
    if "PYTEST_XDIST_WORKER" in os.environ:
        root = root.parent  # the session's base folder, above the workers' own
    out = root / "shared" / name
    out.parent.mkdir(exist_ok=True)
    done = out.with_name(name + ".done")
    with FileLock(str(out) + ".lock"):
        if not done.exists():
            shutil.rmtree(out, ignore_errors=True)
            make(out)
            done.touch()
    return out


@pytest.fixture(scope="session")
def small_data(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """48 scenes at 320x240 (train 36 / val 8 / test 4)."""
    from edgepick.data.synth import SynthConfig, synthesize

    def make(out: Path) -> None:
        synthesize(out, SynthConfig(scenes=48, width=320, height=240, seed=7, splits=(36, 8, 4)), progress=False)
    return shared(tmp_path_factory, "synth", make)


@pytest.fixture(scope="session")
def trained_run(small_data: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A short CPU training run (MobileNetV3, 128x96) shared by the eval and quality tests."""
    from edgepick.geometry import Size
    from edgepick.train.loop import TrainConfig, train

    def make(out: Path) -> None:
        import torch

        threads = torch.get_num_threads()
        torch.set_num_threads(2)  # as without xdist: a worker that needs the run waits for it meanwhile
        try:
            train(TrainConfig(data=str(small_data), out=str(out), epochs=EPOCHS, batch_size=4, size=Size(128, 96),
                              device="cpu", lr=2e-3, keep_epochs=[2, EPOCHS - 1]), progress=False)
        finally:
            torch.set_num_threads(threads)
    return shared(tmp_path_factory, "run", make)


@pytest.fixture(scope="session")
def onnx_files(trained_run: Path, small_data: Path, tmp_path_factory: pytest.TempPathFactory) -> dict:
    """trained_run exported by the CLI as a user would: `edgepick export` (fp32.onnx) and `edgepick
    quantize static` on 16 calibration images (static.onnx); each command's JSON under "fp32" and
    "static". Built once for all workers, read only."""
    import json

    def make(out: Path) -> None:
        out.mkdir(parents=True)
        fp32 = run_cli("export", str(trained_run), "--out", str(out / "fp32.onnx"), check=True).stdout
        static = run_cli("quantize", "static", str(trained_run), "--data", str(small_data), "--out",
                         str(out / "static.onnx"), "--calib-images", "16", check=True).stdout
        (out / "fp32.json").write_text(fp32)
        (out / "static.json").write_text(static)
    out = shared(tmp_path_factory, "onnx", make)
    return {name: json.loads((out / f"{name}.json").read_text()) for name in ("fp32", "static")}
