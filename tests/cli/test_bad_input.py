"""A user's mistakes, command by command: each ends with edgepick's own single line on stderr,
the documented exit status (2), no traceback, and nothing written.

Run in-process through `edgepick.cli.run` (the console entry point's own function) with the
file descriptors captured, so OpenCV's C++ warnings would show up too. One subprocess test per
kind of entry (tests/cli/test_cli.py) and a base-install run of a [train] command
(tests/runtime/test_base_install.py) cover the same rule as a user starts edgepick.
"""

from __future__ import annotations

import json
import os
import shutil

import cv2
import numpy as np
import pytest

pytest.importorskip("onnx")

from edgepick.cli import run  # noqa: E402
from edgepick.geometry import Intrinsics  # noqa: E402
from tests.runtime.test_pipeline import red_model  # noqa: E402
from tests.runtime.test_session import red_channel_model  # noqa: E402

HEADER = "cam_x,cam_y,cam_z,robot_x,robot_y,robot_z"


def _pairs(path, camera, robot):
    rows = [HEADER] + [",".join(f"{v:.6f}" for v in (*c, *r)) for c, r in zip(camera, robot)]
    path.write_text("\n".join(rows) + "\n")
    return path


@pytest.fixture(scope="module")
def ws(tmp_path_factory, small_data):
    """The workspace every case runs in: a data set, one with an odd-sized image, a model, pairs,
    a depth frame, intrinsics, and a plain file to stand where a folder should be."""
    w = tmp_path_factory.mktemp("bad-input")
    mixed = w / "mixed"
    shutil.copytree(small_data, mixed)
    first = sorted((mixed / "train" / "rgb").glob("*.png"))[0]
    cv2.imwrite(str(first), cv2.resize(cv2.imread(str(first)), (200, 100)))
    red_model(w / "model.onnx")
    (w / "afile").write_text("not a folder")
    (w / "busy.run").mkdir()
    (w / "busy.run" / "note.txt").write_text("someone else's")
    rng = np.random.default_rng(0)
    cam = rng.uniform(-0.2, 0.2, (8, 3)) + [0, 0, 0.6]
    R = np.array([[0, -1, 0], [-1, 0, 0], [0, 0, -1]], float)
    rob = cam @ R.T + [0.3, 0.1, 0.7]
    _pairs(w / "pairs.csv", cam, rob)
    _pairs(w / "mirror.csv", cam * [1, 1, -1] + [0, 0, 1.2], rob)  # a camera frame with z flipped
    _pairs(w / "mm.csv", cam, rob * 1000)  # robot side in millimetres
    _pairs(w / "scale.csv", cam, (cam @ R.T) * 5 + [0.3, 0.1, 0.7])  # spread 5x: different units
    _pairs(w / "huge.csv", np.vstack([cam[:-1], [[1e300, 0, 0]]]), rob)
    intr = Intrinsics.d415(320, 240).to_dict()
    (w / "intr.json").write_text(json.dumps(intr))
    (w / "intr0.json").write_text(json.dumps({**intr, "depth_scale": 0}))
    # values no camera has (docs/contracts.md#intrinsics-and-calibration)
    for name, change in {"fx": {"fx": 1e-9}, "fy": {"fy": 1e7}, "cx": {"cx": 1e9}, "cy": {"cy": -400},
                         "scale": {"depth_scale": 1000}, "fine": {"depth_scale": 1e-9}}.items():
        (w / f"intr-{name}.json").write_text(json.dumps({**intr, **change}))
    far = {"R": np.eye(3).tolist(), "t": [1e9, 0, 0.5], "rmse_m": 0.001, "n_pairs": 8}
    (w / "far.json").write_text(json.dumps(far))
    (w / "mm.json").write_text(json.dumps({**far, "t": [300.0, 100.0, 700.0]}))  # millimetres
    labels = np.zeros((240, 320), np.uint8)
    cv2.rectangle(labels, (100, 80), (160, 120), 4, -1)
    cv2.imwrite(str(w / "mask.png"), labels)
    cv2.imwrite(str(w / "rgb.png"), np.dstack([labels] * 3))  # red_model's labels: the mask's
    two = {"edgepick.classes": json.dumps(["background", "bearing"]), "edgepick.input_size": json.dumps([240, 320]),
           "edgepick.colorspace": "rgb", "edgepick.precision": "fp32"}
    red_channel_model(w / "two.onnx", 240, 320, meta=two)  # labels up to 255, metadata for 2 classes
    cv2.imwrite(str(w / "depth.png"), np.full((240, 320), 600, np.uint16))
    cv2.imwrite(str(w / "depth8.png"), np.full((240, 320), 60, np.uint8))
    return {"W": w, "D": small_data, "MIXED": mixed, "MODEL": w / "model.onnx", "F": w / "afile"}


M = ["pick", "--model", "{MODEL}"]
G = ["grasp", "--mask", "{W}/mask.png", "--depth", "{W}/depth.png", "--intrinsics", "{W}/intr.json"]
CASES = [
    # the command line itself
    (["frobnicate"], "No such command"),
    (["train"], "Missing argument 'DATA'"),
    (["train", "{D}", "--out", "{W}/r", "--lr", "abc"], "'abc' is not a valid float"),
    (["train", "{D}", "--out", "{W}/r", "--augment", "hazard"], "'hazard' is not one of 'basic', 'lights'"),
    (["data", "preview", "{D}", "--out", "{W}/p.png", "--split", "dev"], "'dev' is not one of"),
    # data
    (["data", "synth", "{W}/s", "--seed", "-1"], "--seed -1"),
    (["data", "synth", "{W}/s", "--scenes", "2"], "at least 3"),
    (["data", "synth", "{W}/s", "--size", "10x10"], "out of range"),
    (["data", "synth", "{W}/s", "--splits", "a,b"], "--splits"),
    (["data", "synth", "{F}/s"], "is a file, not a folder"),
    (["data", "synth", "{D}"], "not empty"),
    (["data", "preview", "{D}", "--out", "{W}/p.png", "--count", "0"], "--count 0"),
    (["data", "preview", "{D}", "--out", "{W}/p"], "must end in .png"),
    (["data", "preview", "{MIXED}", "--out", "{W}/p.png"], "all images of a data set must have one size"),
    (["data", "preview", "{W}/nothing", "--out", "{W}/p.png"], "not an edgepick data set"),
    (["data", "import", "cvat", "{W}/nothing", "{W}/imp", "--depth-scale", "0"], "--depth-scale"),
    (["data", "import", "cvat", "{W}/nothing", "{W}/imp", "--depth-scale", "1000"],
     "--depth-scale 1000.0: must be in [1e-06, 0.01] metres per depth unit"),
    (["data", "import", "bop", "{W}/nothing", "{W}/imp", "--splits", "a,b"], "--splits"),
    (["data", "import", "bop", "{W}/nothing", "{F}/imp"], "is a file, not a folder"),
    (["data", "capture", "{W}/cap", "--camera", "synth", "--count", "0"], "--count"),
    # train, eval, demo
    (["train", "{D}", "--out", "{F}/r"], "is a file, not a folder"),
    (["train", "{D}", "--out", "{W}/r", "--lr", "-1", "--size", "64x48"], "--lr -1"),
    (["train", "{D}", "--out", "{W}/r", "--lr", "nan", "--size", "64x48"], "--lr nan"),
    (["train", "{D}", "--out", "{W}/r", "--size", "96x128"], "on their side"),
    (["train", "{MIXED}", "--out", "{W}/r", "--size", "64x48", "--epochs", "1"], "all images of a data set"),
    (["eval", "{MODEL}", "{MIXED}", "--split", "train"], "all images of a data set"),
    (["eval", "{MODEL}", "{D}", "--out", "{F}/e.json"], "is a file, not a folder"),
    (["eval", "{W}/none.onnx", "{D}"], "none.onnx"),
    (["demo", "--epochs", "0", "--workdir", "{W}/demo"], "--epochs 0"),
    (["demo", "--epochs", "99", "--workdir", "{W}/demo"], "--epochs 99"),
    # calibrate
    (["calibrate", "{W}/none.csv", "--out", "{W}/c.json"], "cannot read"),
    (["calibrate", "{W}/huge.csv", "--out", "{W}/c.json"], "beyond 10 m"),
    (["calibrate", "{W}/mm.csv", "--out", "{W}/c.json"], "millimetres given?"),
    (["calibrate", "{W}/scale.csv", "--out", "{W}/c.json"], "are both sides in metres?"),
    (["calibrate", "{W}/mirror.csv", "--out", "{W}/c.json"], "an axis has the wrong sign"),
    (["calibrate", "{W}/pairs.csv", "--out", "{F}/c.json"], "is a file, not a folder"),
    (["calibrate", "{W}/pairs.csv", "--out", "{W}/c.json", "--max-rmse", "0"], "--max-rmse"),
    # grasp
    ([*G[:5], "--intrinsics", "{W}/intr0.json"], "depth_scale must be above 0"),
    ([*G[:5], "--intrinsics", "{W}/intr-fx.json"], "fx must be in [16, 32000] px for an image 320 px in width"),
    ([*G[:5], "--intrinsics", "{W}/intr-fy.json"], "fy must be in [12, 24000] px for an image 240 px in height"),
    ([*G[:5], "--intrinsics", "{W}/intr-cx.json"], "cx must lie within one image width of the 320 px image"),
    ([*G[:5], "--intrinsics", "{W}/intr-cy.json"], "cy must lie within one image height of the 240 px image"),
    ([*G[:5], "--intrinsics", "{W}/intr-scale.json"], "depth_scale must be in [1e-06, 0.01] metres per depth unit"),
    ([*G[:5], "--intrinsics", "{W}/intr-fine.json"], "depth_scale must be in [1e-06, 0.01]"),
    ([*G, "--calib", "{W}/far.json"], "t puts the camera 1e+09 m from the robot's base"),
    ([*G, "--classes", "background,box,box"], "names 'box' twice"),
    # a model whose labels go beyond its classes (the grasp step would drop their regions without a word)
    (["grasp", "--model", "{W}/two.onnx", "--rgb", "{W}/rgb.png", *G[3:]],
     "two.onnx gave class id 4, but its edgepick.classes names 2 classes (ids 0 to 1)"),
    (["pick", "--model", "{W}/two.onnx", "--log", "{W}/p.jsonl"], "but its edgepick.classes names 2 classes"),
    ([*G[:3], "--depth", "{W}/depth8.png", *G[5:]], "uint16"),
    ([*G, "--overlay", "{W}/o"], "must end in .png"),
    ([*G, "--classes", ""], "--classes ''"),
    (["grasp", "--mask", "{W}/none.png", *G[3:]], "cannot read"),
    (["grasp", "--model", "{MODEL}", *G[3:]], "--model needs --rgb"),
    # pick
    ([*M, "--speed", "0.5"], "--speed 0.5"),
    ([*M, "--speed", "nan"], "--speed nan"),
    ([*M, "--speed", "0"], "--speed 0"),
    ([*M, "--acc", "-1"], "--acc -1"),
    ([*M, "--class", "spoon"], "--class spoon: not a class"),
    ([*M, "--camera", "synth-cell:abc"], "must be a whole number"),
    ([*M, "--log", "{F}/l.jsonl"], "is a file, not a folder"),
    ([*M, "--overlay-dir", "{F}"], "is a file"),
    ([*M, "--camera", "dir:{W}/nothing", "--log", "{W}/l.jsonl"], "has no intrinsics.json"),
    ([*M, "--camera", "synth", "--calib", "{W}/none.json"], "none.json"),
    ([*M, "--camera", "synth", "--calib", "{W}/mm.json"], "t puts the camera 768.1 m from the robot's base"),
    # export, quantize, bench
    (["export", "{W}/none", "--out", "{W}/m.txt"], "must end in .onnx"),
    (["export", "{W}/none", "--out", "{W}/m.onnx"], "no checkpoint"),
    (["quantize", "static", "{W}/none", "--data", "{D}", "--out", "{F}/q.onnx"], "is a file, not a folder"),
    (["quantize", "static", "{MODEL}", "--calib", "{W}", "--bias-correction", "fast", "--out", "{W}/q.onnx"],
     "--bias-correction fast is for a RUN"),
    (["quantize", "static", "{W}/none", "--data", "{D}", "--adaround-budget", "0", "--out", "{W}/q.onnx"],
     "--adaround-budget 0"),
    (["quantize", "static", "{W}/none", "--data", "{D}", "--placement", "convs", "--out", "{W}/q.onnx"],
     "--placement convs is for an .onnx MODEL"),
    (["quantize", "static", "{W}/none", "--data", "{D}", "--gelu", "sigmoid", "--out", "{W}/q.onnx"],
     "--gelu sigmoid is for an .onnx MODEL"),
    (["quantize", "static", "{W}/none", "--data", "{D}", "--no-adaround-if-far", "--out", "{W}/q.onnx"],
     "--no-adaround-if-far is for an .onnx MODEL"),
    (["quantize", "static", "{MODEL}", "--calib", "{W}", "--gelu", "sigmoid", "--placement", "convs", "--out",
      "{W}/q.onnx"], "--gelu sigmoid: with --placement convs"),
    (["quantize", "hybrid", "{W}/none", "--data", "{D}", "--qat-fraction", "0.1", "--out", "{W}/h.onnx", "--run",
      "{W}/busy.run"], "not empty"),
    (["quantize", "hybrid", "{W}/none", "--data", "{D}", "--qat-fraction", "1.5", "--out", "{W}/h.onnx"],
     "--qat-fraction"),
    (["bench", "{MODEL}", "--data", "{D}", "--out", "{F}/b"], "is a file, not a folder"),
    (["bench", "{MODEL}", "--data", "{D}", "--runs", "0", "--out", "{W}/b"], "--runs"),
    (["bench", "{MODEL}", "--data", "{D}", "--gpu-checkpoint", "{W}/nosuch.pt", "--out", "{W}/b"],
     "--gpu-checkpoint {W}/nosuch.pt: no checkpoint there"),
    (["bench", "{MODEL}", "--cell", "1", "--gpu-checkpoint", "{W}/nosuch.pt", "--out", "{W}/b"],
     "--gpu-checkpoint is for the table of --data"),
]


def _tree(root) -> set[str]:
    return {os.path.relpath(os.path.join(d, f), root) for d, dirs, files in os.walk(root) for f in files + dirs}


def _fill(arg: str, ws: dict) -> str:
    for key, value in ws.items():
        arg = arg.replace("{" + key + "}", str(value))
    return arg


@pytest.mark.parametrize("args, message", CASES, ids=[" ".join(a)[:60] for a, _ in CASES])
def test_a_mistake_is_one_line_exit_2_and_nothing_written(ws, capfd, monkeypatch, args, message):
    monkeypatch.chdir(ws["W"])  # a default output (picks.jsonl) would land here
    before = _tree(ws["W"]), _tree(ws["D"])
    code = run([_fill(a, ws) for a in args])
    assert_refused(code, *capfd.readouterr(), _fill(message, ws))
    assert (_tree(ws["W"]), _tree(ws["D"])) == before, "something was written"


def assert_refused(code: int, out: str, err: str, message: str) -> None:
    """Exit 2, one line on stderr that is edgepick's and holds MESSAGE, nothing on stdout."""
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2, err
    assert len(lines) == 1 and lines[0].startswith("edgepick: error: "), err
    assert message in lines[0], lines[0]
    assert out == ""


@pytest.fixture(scope="module")
def runws(ws, trained_run, tmp_path_factory):
    """ws plus a trained float RUN (kept epochs 2 and 24 of 25), a data set with other class names,
    one with a mask missing (half-written) and one with an image that is not a PNG."""
    w = tmp_path_factory.mktemp("bad-input-run")
    other, broken, unreadable = w / "other", w / "broken", w / "unreadable"
    for copy in (other, broken, unreadable):
        shutil.copytree(ws["D"], copy)
    meta = json.loads((other / "meta.json").read_text())
    meta["classes"] = meta["classes"][:-1] + ["crate"]
    (other / "meta.json").write_text(json.dumps(meta))
    (broken / "train" / "mask" / "000003.png").unlink()
    (unreadable / "train" / "rgb" / "000005.png").write_bytes(b"not a png")
    return {**ws, "RUN": trained_run, "OTHER": other, "BROKEN": broken, "UNREADABLE": unreadable, "V": w}


H = ["quantize", "hybrid", "{RUN}", "--data", "{D}", "--out", "{V}/m.onnx"]
S = ["quantize", "static", "{RUN}", "--out", "{V}/m.onnx"]
RUN_CASES = [
    ([*H, "--qat-fraction", "0.04", "--freeze-at", "1.5"], "--freeze-at"),
    ([*H, "--qat-fraction", "0.04", "--weight-averaging", "0"], "--weight-averaging"),
    ([*H, "--qat-fraction", "0.5"], "--keep-epochs 12"),
    ([*H, "--qat-fraction", "0.04", "--calib-images", "0", "--hold-ranges"], "--hold-ranges needs it"),
    ([*H, "--qat-fraction", "0.04", "--calib-images", "999"], "calibration images"),
    ([*S, "--data", "{D}", "--calib-images", "500"], "calibration images"),
    ([*S, "--data", "{OTHER}"], "classes"),
    ([*S, "--data", "{D}", "--keep-float", "nope.3"], "--keep-float names no module"),
    (["eval", "{RUN}", "{OTHER}"], "classes"),
    (["train", "{BROKEN}", "--out", "{V}/r", "--epochs", "1"], "half-written"),
    (["train", "{UNREADABLE}", "--out", "{V}/r", "--epochs", "1", "--size", "96x64"], "cannot read image"),
    (["train", "{D}", "--out", "{V}/r", "--resume"], "nothing to resume"),
    (["train", "{D}", "--out", "{V}/r", "--epoch-images", "-1", "--size", "96x64"], "--epoch-images"),
    (["train", "{D}", "--out", "{V}/r", "--arch", "vgg"], "Invalid value for '--arch'"),
    (["train", "{D}", "--out", "{V}/r", "--size", "480x640"], "did you mean 640x480?"),
]


@pytest.mark.parametrize("args, message", RUN_CASES, ids=[" ".join(a)[:60] for a, _ in RUN_CASES])
def test_a_mistake_with_a_trained_run_is_one_line_and_nothing_written(runws, capfd, monkeypatch, args, message):
    """The same rule for the commands that start from a float run: checked before any training or
    calibration, or (an unreadable image) failing in the first epoch with no RUN folder left."""
    monkeypatch.chdir(runws["V"])
    roots = [runws[k] for k in ("V", "D", "RUN", "OTHER", "BROKEN")]
    before = [_tree(r) for r in roots]
    code = run([_fill(a, runws) for a in args])
    out, err = capfd.readouterr()
    lines = [line for line in err.splitlines() if line.strip() and not line.startswith("epoch ")]
    assert code == 2, err
    assert len(lines) == 1 and lines[0].startswith("edgepick: error: "), err
    assert message in lines[0], lines[0]
    assert [_tree(r) for r in roots] == before, "something was written"


def test_there_are_at_least_40_cases():
    assert len(CASES) >= 40
