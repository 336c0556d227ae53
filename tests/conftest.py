"""Shared fixtures: one small synthetic data set and one short training run per test session.

`make test` runs the suite on two pytest-xdist workers: most of a quantization test's time is
single-threaded Python (torch.export, pattern matching), so one worker alone leaves a 2-core machine
half idle. Each test file runs on one worker (`--dist loadfile`), so a module fixture is built
once (`--dist loadgroup` would be finer, but with pytest 9.2 xdist 3.8 ignores its groups:
pytest-dev/pytest-xdist#1386). The session fixtures are built once for all workers (under a file
lock, tests/shared_builds.py), in the background from the session's start, and read only. The
files go to the workers in the order `pytest_collection_modifyitems` leaves them: those that need
no training run first, the heaviest first within each part (xdist's own reordering, by test count,
is turned off), so that the run trains while the workers are busy and no file is left alone at the
end."""

from __future__ import annotations

import os
import subprocess
from collections.abc import Sequence
from pathlib import Path

import pytest

from edgepick.runtime.grasp_record import NO_DEPTH, Grasp
from tests.shared_builds import EPOCHS, run_cli, run_exports, short_run, start_in_background, synth_data  # noqa: F401

# One OpenMP thread per xdist worker: two workers with two threads each would run four threads on 2 cores, and
# OpenMP's barriers then wait on threads the kernel has descheduled: several times slower. Set, not defaulted: the
# controller's own conftest runs first and its value would reach the workers through their environment.
if "PYTEST_XDIST_WORKER" in os.environ:
    os.environ["OMP_NUM_THREADS"] = "1"
else:
    os.environ.setdefault("OMP_NUM_THREADS", "2")
REPO = Path(__file__).resolve().parents[1]


TRAINED = {"trained_run", "onnx_files"}  # fixtures built on a training run: `make check` leaves their tests out


def pytest_configure(config: pytest.Config) -> None:
    config.option.loadscopereorder = False  # keep the file order below (xdist's reorder goes by test count)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Mark every test that needs the session's training run `trained` (`-m "not trained"` skips them),
    then order the files: those needing no run first, and within each part the files with the most
    tests marked slow first (a stable sort: each file's own order is kept)."""
    files: dict[Path, list[pytest.Item]] = {}
    for item in items:
        if TRAINED & set(getattr(item, "fixturenames", ())):
            item.add_marker(pytest.mark.trained)
        files.setdefault(item.path, []).append(item)

    def weight(group: list[pytest.Item]) -> tuple[bool, int]:
        return (any(i.get_closest_marker("trained") for i in group),
                -sum(bool(i.get_closest_marker("slow")) for i in group))
    items[:] = [item for group in sorted(files.values(), key=weight) for item in group]


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


def session_root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The session's base folder, above the xdist workers' own: where the shared builds go."""
    root = tmp_path_factory.getbasetemp()
    return root.parent if "PYTEST_XDIST_WORKER" in os.environ else root


@pytest.fixture(scope="session", autouse=True)
def builds_in_background(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory):
    """The first worker starts the shared builds in a process of their own when any test of the
    session needs the training run, and waits for it at the session's end."""
    needed = any(item.get_closest_marker("trained") for item in request.session.items)
    proc = start_in_background(session_root(tmp_path_factory)) if needed and worker_index() == 0 else None
    yield
    if proc is not None:
        try:
            proc.wait(timeout=600)  # the builds take a few minutes at most; a stopped session must not hang here
        except subprocess.TimeoutExpired:
            proc.kill()


@pytest.fixture(scope="session")
def small_data(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """48 scenes at 320x240 (train 36 / val 8 / test 4)."""
    return synth_data(session_root(tmp_path_factory))


@pytest.fixture(scope="session")
def trained_run(small_data: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A short CPU training run (MobileNetV3, 128x96, EPOCHS epochs) shared by the eval and quality tests."""
    return short_run(session_root(tmp_path_factory))


@pytest.fixture(scope="session")
def onnx_files(trained_run: Path, small_data: Path, tmp_path_factory: pytest.TempPathFactory) -> dict:
    """trained_run exported by the CLI as a user would: `edgepick export` (fp32.onnx) and `edgepick
    quantize static` on 16 calibration images (static.onnx); each command's JSON under "fp32" and
    "static". Built once for all workers, read only."""
    import json

    out = run_exports(session_root(tmp_path_factory))
    return {name: json.loads((out / f"{name}.json").read_text()) for name in ("fp32", "static")}
