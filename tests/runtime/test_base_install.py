"""The laptop install: `pip install .` without extras (no torch, no onnx) runs `edgepick calibrate`
and `edgepick grasp` in both modes. Builds a real venv from a copy of the sources (~1 min)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys

import cv2
import numpy as np
import pytest

from edgepick.geometry import Intrinsics
from tests.conftest import REPO

pytestmark = pytest.mark.slow


def _run(*cmd, cwd=None, timeout=600):
    return subprocess.run([str(c) for c in cmd], capture_output=True, text=True, timeout=timeout, cwd=cwd)


@pytest.fixture(scope="module")
def base_venv(tmp_path_factory):
    root = tmp_path_factory.mktemp("base")
    src = root / "src"  # a copy: building in the checkout would leave build/ and egg-info behind
    src.mkdir()
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(REPO / name, src / name)
    shutil.copytree(REPO / "edgepick", src / "edgepick", ignore=shutil.ignore_patterns("__pycache__"))
    venv = root / "venv"
    proc = _run(sys.executable, "-m", "venv", venv)
    assert proc.returncode == 0, proc.stderr
    proc = _run(venv / "bin" / "python", "-m", "pip", "install", "-q", str(src))
    assert proc.returncode == 0, proc.stderr[-2000:]
    return venv


def test_base_install_has_no_torch_and_runs_calibrate_and_grasp(base_venv, tmp_path):
    py, exe = base_venv / "bin" / "python", base_venv / "bin" / "edgepick"
    for heavy in ("torch", "torchao", "onnx"):
        proc = _run(py, "-c", f"import {heavy}")
        assert proc.returncode != 0, f"{heavy} is in the base install"

    rng = np.random.default_rng(0)
    cam = rng.uniform(-0.2, 0.2, (6, 3)) + [0, 0, 0.6]
    rob = cam @ np.array([[0, -1, 0], [-1, 0, 0], [0, 0, -1]]).T + [0.3, 0.1, 0.7]
    lines = ["cam_x,cam_y,cam_z,robot_x,robot_y,robot_z"] + [",".join(f"{v:.6f}" for v in (*c, *r)) for c, r in
                                                             zip(cam, rob)]
    (tmp_path / "pairs.csv").write_text("\n".join(lines) + "\n")
    proc = _run(exe, "calibrate", tmp_path / "pairs.csv", "--out", tmp_path / "calib.json")
    assert proc.returncode == 0, proc.stderr
    assert json.loads((tmp_path / "calib.json").read_text())["rmse_m"] < 1e-6

    intr = Intrinsics.d415(320, 240)
    (tmp_path / "intr.json").write_text(json.dumps(intr.to_dict()))
    labels = np.zeros((240, 320), np.uint8)
    cv2.rectangle(labels, (60, 80), (200, 130), 4, -1)
    rgb = np.zeros((240, 320, 3), np.uint8)
    rgb[..., 0] = labels
    cv2.imwrite(str(tmp_path / "mask.png"), labels)
    cv2.imwrite(str(tmp_path / "rgb.png"), rgb[..., ::-1])
    cv2.imwrite(str(tmp_path / "depth.png"), np.full((240, 320), 650, np.uint16))
    common = ["--depth", tmp_path / "depth.png", "--intrinsics", tmp_path / "intr.json", "--calib", tmp_path / "calib.json"]
    mask = _run(exe, "grasp", "--mask", tmp_path / "mask.png", *common)
    assert mask.returncode == 0, mask.stderr
    (rec,) = json.loads(mask.stdout)
    assert rec["class"] == "box" and len(rec["pose_robot"]) == 6

    pytest.importorskip("onnx")  # the model file is built here, in the test's own environment
    from tests.runtime.test_pipeline import red_model

    model = _run(exe, "grasp", "--model", red_model(tmp_path / "m.onnx"), "--rgb", tmp_path / "rgb.png", *common)
    assert model.returncode == 0, model.stderr
    assert json.loads(model.stdout) == [rec]


@pytest.mark.parametrize("args", [["train", "DATA", "--out", "RUN"], ["export", "RUN", "--out", "m.onnx"],
                                  ["quantize", "static", "RUN", "--data", "DATA", "--out", "q.onnx"]])
def test_a_train_command_on_the_base_install_names_the_extra(base_venv, tmp_path, args):
    from edgepick.data.synth import SynthConfig, synthesize

    synthesize(tmp_path / "DATA", SynthConfig(scenes=3, width=64, height=48), progress=False)
    before = sorted(p.name for p in tmp_path.iterdir())
    proc = _run(base_venv / "bin" / "edgepick", *args, cwd=tmp_path)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1, proc.stderr
    assert "needs the [train] extra" in lines[0] and "pip install 'edgepick[train]'" in lines[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == before  # nothing written
