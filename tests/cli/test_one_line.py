"""One line means one line: a refusal that a command can find before its work prints its error line
alone, with no progress line, stage line or warning before it. Each case here is a mistake that the
command's work would meet only after such a line (a stage of a quantization pass, a bench row's
progress line, a dropped environment variable's warning, calibrate's outlier line, the demo's first
step), had the command not checked it first.

In-process through `edgepick.cli.run` with the file descriptors captured, as tests/cli/test_bad_input.py
runs its cases; tests/cli/test_bad_files.py runs the thread variable's case in a subprocess too, where
libgomp reads it.
"""

from __future__ import annotations

import json
import shutil

import cv2
import numpy as np
import pytest

torch = pytest.importorskip("torch")

from edgepick.cli import run  # noqa: E402
from tests.cli.test_bad_input import _fill, _pairs, _tree, assert_refused  # noqa: E402
from tests.runtime.test_pipeline import red_model  # noqa: E402


@pytest.fixture(scope="module")
def ws(tmp_path_factory, small_data):
    """Broken copies of the small data set, a short float run with a kept epoch for hybrid-QaT, pairs
    with noise and one outlier, and a model."""
    from edgepick.geometry import Size
    from edgepick.train.loop import TrainConfig, train

    w = tmp_path_factory.mktemp("one-line")
    mixed, unreadable, other, few_val = w / "mixed", w / "unreadable", w / "other", w / "few-val"
    for copy in (mixed, unreadable, other, few_val):
        shutil.copytree(small_data, copy)
    first = sorted((mixed / "train" / "rgb").glob("*.png"))[1]
    cv2.imwrite(str(first), cv2.resize(cv2.imread(str(first)), (200, 100)))
    (unreadable / "val" / "rgb" / "000003.png").write_bytes(b"not a png")
    meta = json.loads((other / "meta.json").read_text())
    meta["classes"] = meta["classes"][:-1] + ["crate"]
    (other / "meta.json").write_text(json.dumps(meta))
    for sid in sorted(p.stem for p in (few_val / "val" / "rgb").glob("*.png"))[2:]:  # 2 val images: a warning
        for kind in ("rgb", "mask", "depth"):
            (few_val / "val" / kind / f"{sid}.png").unlink(missing_ok=True)
    train(TrainConfig(data=str(small_data), out=str(w / "run"), epochs=4, batch_size=4, size=Size(64, 48),
                      device="cpu", keep_epochs=[3]), progress=False)
    rng = np.random.default_rng(1)
    cam = rng.uniform(-0.2, 0.2, (10, 3)) + [0, 0, 0.6]
    rob = cam @ np.array([[0, -1, 0], [-1, 0, 0], [0, 0, -1]], float).T + [0.3, 0.1, 0.7]
    rob += rng.normal(0, 0.003, rob.shape)  # 3 mm of noise: a fit of about 5 mm RMSE
    rob[4] += [0.05, 0, 0]  # one pair 5 cm off: an outlier
    _pairs(w / "outlier.csv", cam, rob)
    return {"W": w, "D": small_data, "RUN": w / "run", "MIXED": mixed, "UNREADABLE": unreadable, "OTHER": other,
            "FEW": few_val, "MODEL": red_model(w / "model.onnx")}


Q = ["quantize", "qat", "--out", "{W}/q.onnx", "--size", "64x48", "--epochs", "1", "--data"]
H = ["quantize", "hybrid", "{RUN}", "--out", "{W}/h.onnx", "--qat-fraction", "0.25", "--data"]
NO_CUDA = pytest.mark.skipif(torch.cuda.is_available(), reason="refused only where there is no CUDA device")
CASES = [  # (environment, args, message); each met, unchecked, after a line on stderr
    # a stage line of a QaT pass ("prepare the fake-quant graph ..."), then what its training found
    ({}, [*Q, "{MIXED}"], "all images of a data set must have one size"),
    ({}, [*Q, "{UNREADABLE}"], "cannot read image"),
    pytest.param({}, [*Q, "{D}", "--device", "cuda"], "--device cuda: asked for, but no CUDA device", marks=NO_CUDA),
    ({"WORLD_SIZE": "2", "MASTER_ADDR": "127.0.0.1", "MASTER_PORT": "29500"}, [*Q, "{D}"], "RANK not set"),
    ({}, [*H, "{MIXED}"], "all images of a data set must have one size"),
    pytest.param({}, [*H, "{D}", "--device", "cuda"], "--device cuda: asked for, but no CUDA device", marks=NO_CUDA),
    # bench's "bench MODEL ..." line, then the model's classes against the data set's
    ({}, ["bench", "{MODEL}", "--data", "{OTHER}", "--out", "{W}/b"], "differ from the data set's"),
    # the accuracy-aware search's warning about few val images, then a module name that is not the model's
    ({}, ["quantize", "static", "{RUN}", "--data", "{FEW}", "--out", "{W}/s.onnx", "--max-miou-drop", "1",
          "--keep-float", "nope.3"], "--keep-float names no module"),
    # calibrate's "dropping N outlier pair(s)", then a fit still too poor
    ({}, ["calibrate", "{W}/outlier.csv", "--out", "{W}/c.json", "--drop-outliers", "--max-rmse", "1"],
     "the fit's RMSE"),
    # the demo's first step line, then the scenes' room
    ({}, ["demo", "--workdir", "{W}/demo", "--scenes", "2000000"], "beyond the 1000000"),
    # a dropped thread variable's warning, then any refusal
    ({"OMP_NUM_THREADS": "0"}, ["export", "{W}/none", "--out", "{W}/m.onnx"], "no checkpoint"),
    ({"MKL_NUM_THREADS": "x"}, [*Q, "{MIXED}"], "all images of a data set must have one size"),
]


def _ids(case) -> str:
    values = case.values if hasattr(case, "values") else case
    return " ".join(values[1])[:60]


@pytest.mark.parametrize("env, args, message", CASES, ids=[_ids(c) for c in CASES])
def test_a_refusal_is_its_one_line_with_nothing_before_it(ws, capfd, monkeypatch, env, args, message):
    monkeypatch.chdir(ws["W"])
    for key in ("WORLD_SIZE", "RANK", "LOCAL_RANK", "MASTER_ADDR", "MASTER_PORT"):
        monkeypatch.delenv(key, raising=False)
    for key, value in env.items():
        monkeypatch.setenv(key, value)
    before = _tree(ws["W"]), _tree(ws["D"])
    code = run([_fill(a, ws) for a in args])
    assert_refused(code, *capfd.readouterr(), message)
    assert (_tree(ws["W"]), _tree(ws["D"])) == before, "something was written"


def test_a_dropped_thread_variable_is_said_after_a_command_that_runs(ws, capfd, monkeypatch):
    """The warning is not lost: a command that runs prints it once, after its own output."""
    monkeypatch.setenv("OMP_NUM_THREADS", "0")
    assert run(["data", "synth", str(ws["W"] / "s"), "--scenes", "3", "--size", "64x48", "--workers", "1"]) == 0
    out, err = capfd.readouterr()
    assert json.loads(out)["scenes"] == 3
    lines = [line for line in err.splitlines() if line.strip()]
    assert lines == ["edgepick: warning: OMP_NUM_THREADS='0' is not a positive whole number; ignored (the libraries "
                     "chose their thread counts)"], err
    shutil.rmtree(ws["W"] / "s")
