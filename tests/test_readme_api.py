"""The Python API's walk-through (docs/python-api.md, linked from the README) runs as written: its
first block end to end on a tiny data set (train, export, static PTQ), the runtime block on the file
it made, the smaller verbs (prepare, fit, calibrate, convert) on that run, and every import of the
page resolves to a public name (one in its package's `__all__`). The QaT passes that the page shows
train for minutes; tests/quant/test_passes.py runs them."""

from __future__ import annotations

import ast
import importlib
import json
import re
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
SETTINGS = re.compile(r"^data, size, epochs = .*$", re.M)


API_PAGE = REPO / "docs" / "python-api.md"


def api_blocks() -> list[str]:
    """The ```python blocks of docs/python-api.md, in order."""
    assert "docs/python-api.md" in (REPO / "README.md").read_text(), "the README links the Python API page"
    return re.findall(r"```python\n(.*?)```", API_PAGE.read_text(), re.S)


def test_the_api_section_imports_only_public_names():
    blocks = api_blocks()
    assert len(blocks) >= 4
    for block in blocks:
        for node in ast.walk(ast.parse(block)):
            if isinstance(node, ast.Import):
                raise AssertionError(f"python-api.md imports modules ({ast.unparse(node)}); name the public objects")
            if isinstance(node, ast.ImportFrom):
                assert node.module in ("edgepick", "edgepick.train", "edgepick.quant", "edgepick.export",
                                       "edgepick.runtime"), ast.unparse(node)
                module = importlib.import_module(node.module)
                for alias in node.names:
                    assert alias.name in module.__all__, f"{node.module}.{alias.name} is not public"


@pytest.mark.slow
def test_the_first_api_block_runs_on_a_tiny_data_set(tmp_path, monkeypatch):
    from edgepick.data.synth import SynthConfig, synthesize
    from edgepick.train import Run

    synthesize(tmp_path / "data", SynthConfig(scenes=12, width=128, height=96, seed=3, splits=(8, 2, 2)),
               progress=False)
    first, *_, runtime = api_blocks()
    assert len(SETTINGS.findall(first)) == 1, "the block's settings line moved; update this test"
    monkeypatch.chdir(tmp_path)
    names: dict = {}
    exec(compile(SETTINGS.sub('data, size, epochs = "data", Size(96, 64), 3', first), str(API_PAGE), "exec"), names)
    for name in ("fp32.onnx", "static.onnx"):
        assert (tmp_path / name).is_file(), name
    assert Run(tmp_path / "run").kept_epochs() == [3]  # round(0.9 * 3): where hybrid-QaT 10% would start
    assert names["static"].int8_convs == names["static"].convs and names["static"].agreement_vs_torch > 0.9

    (tmp_path / "calib.json").write_text(json.dumps({"R": np.eye(3).tolist(), "t": [0.1, 0.0, 0.0]}))
    runtime_names: dict = {}
    exec(compile(runtime, str(API_PAGE), "exec"), runtime_names)
    result = runtime_names["result"]
    assert result.labels.shape == (96, 128) and set(result.ms) >= {"inference"}

    (verbs,) = [b for b in api_blocks() if "calibrate(observed" in b]  # the smaller verbs, on the run made above
    small = verbs.replace("epochs=5, size=Size(320, 240)", "epochs=1, size=Size(96, 64)")
    assert small != verbs, "the verbs block's settings moved; update this test"
    exec(compile(small, str(API_PAGE), "exec"), names)  # its `calib`: the first block's images
    assert (tmp_path / "my-qat.run" / "last.pt").is_file() and names["int8"] is not None


def test_the_onnx_block_runs_on_a_model_from_another_exporter(tmp_path, monkeypatch):
    from tests.quant.onnx_models import calib_tensors, export_torch

    (block,) = [b for b in api_blocks() if "quantize_onnx_static" in b]
    export_torch(tmp_path / "model.onnx", opset=12)
    (tmp_path / "calib").mkdir()
    for k, x in enumerate(calib_tensors(4)):
        np.save(tmp_path / "calib" / f"{k}.npy", x)
    monkeypatch.chdir(tmp_path)
    names: dict = {}
    exec(compile(block, str(API_PAGE), "exec"), names)
    assert names["result"].int8_convs == names["result"].convs and (tmp_path / "model-int8.onnx").is_file()
