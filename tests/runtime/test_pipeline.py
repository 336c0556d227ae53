"""Frame -> labels -> grasp records with per-stage times, on a real ONNX model run by onnxruntime."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

pytest.importorskip("onnx")

from edgepick.frames import Frame  # noqa: E402
from edgepick.geometry import Intrinsics  # noqa: E402
from edgepick.runtime.grasp import DEFAULT_CLASSES, grasp_records  # noqa: E402
from edgepick.runtime.pipeline import STAGES, Pipeline, median_ms  # noqa: E402
from edgepick.runtime.session import Segmenter  # noqa: E402
from tests.conftest import run_cli  # noqa: E402
from tests.runtime.test_session import red_channel_model  # noqa: E402

INTR = Intrinsics.d415(320, 240)


def red_model(path, h=240, w=320, divide=1):
    """Labels = the image's red channel integer-divided by DIVIDE, with the synthetic set's class names:
    a frame whose red channel is a label image gives its labels back (DIVIDE 1), and any frame gives
    ids 0 to 3, within the five classes (DIVIDE 64: a stand-in model for a camera's frames)."""
    meta = {"edgepick.classes": json.dumps(list(DEFAULT_CLASSES)), "edgepick.input_size": json.dumps([h, w]),
            "edgepick.colorspace": "rgb", "edgepick.precision": "fp32"}
    return red_channel_model(path, h, w, meta=meta, divide=divide)


def scene():
    """An RGB frame whose red channel is a label image: a box and a bearing ring."""
    labels = np.zeros((240, 320), np.uint8)
    cv2.rectangle(labels, (40, 60), (140, 110), 4, -1)
    cv2.circle(labels, (230, 150), 40, 1, 14)
    rgb = np.zeros((240, 320, 3), np.uint8)
    rgb[..., 0], rgb[..., 1] = labels, 90
    return rgb, labels, np.full((240, 320), 600, np.uint16)


def test_pipeline_records_match_mask_mode_and_time_every_stage(tmp_path):
    rgb, labels, depth = scene()
    pipe = Pipeline(Segmenter(red_model(tmp_path / "m.onnx"), threads=1))
    out = pipe(Frame(rgb, depth, INTR, "f"))
    assert np.array_equal(out.labels, labels)
    assert out.records == grasp_records(labels, depth, INTR, DEFAULT_CLASSES)
    assert [r.cls for r in out.records] == ["box", "bearing"]
    assert list(out.ms) == list(STAGES) and all(v >= 0 for v in out.ms.values())
    med = median_ms([out.ms, pipe(Frame(rgb, depth, INTR, "f")).ms])
    assert med["outside_inference"] <= med["total"] and {"total", *STAGES} <= set(med)


def test_cli_model_mode_with_profile_and_overlay(tmp_path):
    rgb, labels, depth = scene()
    cv2.imwrite(str(tmp_path / "rgb.png"), rgb[..., ::-1])
    cv2.imwrite(str(tmp_path / "mask.png"), labels)
    cv2.imwrite(str(tmp_path / "depth.png"), depth)
    (tmp_path / "intr.json").write_text(json.dumps(INTR.to_dict()))
    common = ["--depth", str(tmp_path / "depth.png"), "--intrinsics", str(tmp_path / "intr.json")]
    model = run_cli("grasp", "--model", str(red_model(tmp_path / "m.onnx")), "--rgb", str(tmp_path / "rgb.png"),
                    "--profile", "--overlay", str(tmp_path / "o.png"), *common, check=True)
    mask = run_cli("grasp", "--mask", str(tmp_path / "mask.png"), *common, check=True)
    assert json.loads(model.stdout) == json.loads(mask.stdout) and len(json.loads(model.stdout)) == 2
    for stage in (*STAGES, "outside_inference"):
        assert f"{stage} " in model.stderr
    assert "grasp sub-steps: filters " in model.stderr and "top face " in model.stderr
    assert cv2.imread(str(tmp_path / "o.png")).shape == (240, 320, 3)


@pytest.mark.parametrize("args, message", [
    ([], "either --mask"), (["--mask", "m.png", "--model", "m.onnx"], "either --mask"),
    (["--model", "m.onnx"], "needs --rgb"), (["--model", "missing.onnx", "--rgb", "RGB"], "no model file"),
    (["--model", "FOREIGN", "--rgb", "RGB"], "not an edgepick model")])
def test_cli_model_mode_bad_input(tmp_path, args, message):
    rgb, labels, depth = scene()
    cv2.imwrite(str(tmp_path / "rgb.png"), rgb[..., ::-1])
    cv2.imwrite(str(tmp_path / "depth.png"), depth)
    (tmp_path / "intr.json").write_text(json.dumps(INTR.to_dict()))
    foreign = red_channel_model(tmp_path / "foreign.onnx", 240, 320, meta={})
    args = [str(foreign) if a == "FOREIGN" else str(tmp_path / "rgb.png") if a == "RGB" else a for a in args]
    proc = run_cli("grasp", *args, "--depth", str(tmp_path / "depth.png"), "--intrinsics", str(tmp_path / "intr.json"))
    assert proc.returncode == 2 and message in proc.stderr and "Traceback" not in proc.stderr
