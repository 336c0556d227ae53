"""`edgepick bench` end to end on tiny contract models run by onnxruntime."""

from __future__ import annotations

import json

import pytest

pytest.importorskip("onnx")

from edgepick.data.synth import SynthConfig, synthesize  # noqa: E402
from edgepick.machine import machine_line  # noqa: E402
from edgepick.runtime.grasp import DEFAULT_CLASSES  # noqa: E402
from tests.conftest import run_cli  # noqa: E402
from tests.runtime.test_session import red_channel_model  # noqa: E402


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench") / "data"
    synthesize(out, SynthConfig(scenes=6, width=160, height=120, seed=2, splits=(2, 1, 3)), progress=False)
    return out


META = {"edgepick.classes": json.dumps(list(DEFAULT_CLASSES)), "edgepick.input_size": json.dumps([120, 160]),
        "edgepick.colorspace": "rgb", "edgepick.precision": "fp32"}


def model(path, precision="fp32", quant=None, train_time=120.0):
    meta = {**META, "edgepick.precision": precision, "edgepick.train_time_s": str(train_time)}
    if quant:
        meta["edgepick.quant"] = json.dumps(quant)
    return str(red_channel_model(path, 120, 160, meta=meta, divide=64))  # ids 0..3 of the 5 classes


def float_checkpoint(path):
    """An untrained float checkpoint of the synthetic set's classes at the data's 160x120: a GPU row's."""
    from edgepick.geometry import Size
    from edgepick.models import ModelConfig, build_model
    from edgepick.train.checkpoint import Checkpoint

    Checkpoint(model_config=ModelConfig(), classes=tuple(DEFAULT_CLASSES), input_size=Size(160, 120),
               model=build_model(ModelConfig()).state_dict()).save(path)
    return str(path)


@pytest.mark.slow
def test_bench_rows_columns_and_files(tmp_path, data):
    torch = pytest.importorskip("torch")
    models = [model(tmp_path / "h5.onnx", "int8", {"mode": "hybrid", "qat_fraction": 0.05}, 130.0),
              model(tmp_path / "fp32.onnx"),
              model(tmp_path / "static.onnx", "int8", {"mode": "static"})]
    proc = run_cli("bench", *models, "--data", str(data), "--runs", "5", "--out", str(tmp_path / "out"),
                   "--gpu-checkpoint", float_checkpoint(tmp_path / "float.pt"))
    assert proc.returncode == 0, proc.stderr
    result = json.loads(proc.stdout)
    gpu = ["fp32 GPU"] if torch.cuda.is_available() else []
    assert [r["mode"] for r in result["rows"]] == [*gpu, "fp32 CPU", "static", "hybrid-QaT 5%"]
    if not gpu:  # no CUDA here: the GPU row is left out, and said so
        assert result["notes"] == ["no CUDA GPU here: the fp32 GPU row is left out"]
        assert "edgepick: warning: no CUDA GPU here: the fp32 GPU row is left out" in proc.stderr.splitlines()
    card = result["rows"][0]["device"] if gpu else None
    result["rows"] = result["rows"][len(gpu):]
    for r in result["rows"]:
        assert 0 <= r["miou"] <= 1 and r["p95_ms"] >= r["p50_ms"] > 0 and r["pipeline_p50_ms"] > 0
    assert result["rows"][2]["train_time_s"] == 130.0
    for kind in ("md", "csv", "json", "png"):
        assert (tmp_path / "out").joinpath(result["reports"][kind]).exists()
    assert "Table 5.6" in (tmp_path / "out" / "table.md").read_text()
    machine = machine_line(card).removeprefix("Machine: ")  # CPU model, int8 flags, cores (GPU): the cell table's line
    assert json.loads((tmp_path / "out" / "table.json").read_text())["context"]["machine"] == machine
    assert f"- machine: {machine}\n" in (tmp_path / "out" / "table.md").read_text()


@pytest.mark.parametrize("case, message", [("not-onnx", "not an .onnx"), ("foreign", "not an edgepick model"),
                                           ("classes", "classes"),
                                           ("ids", "gave class id 255, but its edgepick.classes names 5 classes")])
def test_bench_bad_input(tmp_path, data, case, message):
    if case == "not-onnx":
        path = tmp_path / "m.pt"
        path.write_text("x")
    elif case == "foreign":
        path = red_channel_model(tmp_path / "m.onnx", 120, 160, meta={})
    elif case == "classes":
        path = red_channel_model(tmp_path / "m.onnx", 120, 160)  # its classes: background, a, b
    else:  # the synthetic set's classes, but raw red values (up to 255) as class ids
        path = red_channel_model(tmp_path / "raw.onnx", 120, 160, meta=META)
    proc = run_cli("bench", str(path), "--data", str(data), "--out", str(tmp_path / "out"))
    assert proc.returncode == 2 and message in proc.stderr and "Traceback" not in proc.stderr
    assert not (tmp_path / "out").exists()
