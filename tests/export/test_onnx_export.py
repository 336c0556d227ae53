"""Contract metadata: the training time of a run's best checkpoint is the whole run's."""

from __future__ import annotations

import json

import pytest

pytest.importorskip("torch")

from edgepick.export.onnx_export import run_train_time_s  # noqa: E402


def test_best_checkpoint_reports_the_whole_runs_training_time(tmp_path):
    (tmp_path / "metrics.json").write_text(json.dumps({"epochs": 100, "train_time_s": 228.4}))
    assert run_train_time_s(tmp_path / "best.pt", 111.0) == 228.4
    assert run_train_time_s(tmp_path / "epoch_090.pt", 200.0) == 200.0
    (tmp_path / "metrics.json").write_text("{broken")
    assert run_train_time_s(tmp_path / "best.pt", 111.0) == 111.0


def test_export_passes_are_named_and_an_unknown_one_is_refused(tmp_path):
    import torch

    from edgepick.errors import ConfigError
    from edgepick.export.onnx_export import EXPORT_PASSES, export_onnx

    assert set(EXPORT_PASSES) == {"crop_convs", "integer_activations"}
    with pytest.raises(ConfigError, match="unknown export pass 'fuse'"):
        export_onnx(torch.nn.Conv2d(3, 2, 1), tmp_path / "m.onnx", {}, (32, 32), passes=("fuse",))
    assert not (tmp_path / "m.onnx").exists()


def test_an_int8_graph_is_exported_without_onnxscripts_rewrites_and_loses_nothing(tmp_path, monkeypatch):
    """A converted graph skips the pattern rewrites of `torch.onnx.export(optimize=True)` (they cost
    the export time and change nothing in a QDQ graph): the file has the same ops, in the same
    counts, and the same outputs as with them; a float graph still has its BatchNorm folded."""
    from collections import Counter

    import numpy as np
    import onnx
    import torch

    import edgepick.export.onnx_export as onnx_export
    from edgepick.geometry import Size
    from edgepick.quant import QuantConfig, convert, prepare
    from tests.quant.onnx_models import calib_tensors, run, torch_net

    net = torch_net(two_outputs=True)
    observed = prepare(net, QuantConfig(), Size(96, 64), qat=False)
    with torch.no_grad():
        for x in calib_tensors(4):
            observed(torch.from_numpy(x))
    int8 = convert(observed)
    assert onnx_export._is_quantized(int8) and not onnx_export._is_quantized(net)
    lean = onnx_export.export_module_onnx(int8, tmp_path / "lean.onnx", (1, 3, 64, 96), {})
    monkeypatch.setattr(onnx_export, "_is_quantized", lambda net: False)  # the whole optimizer
    full = onnx_export.export_module_onnx(int8, tmp_path / "full.onnx", (1, 3, 64, 96), {})
    float_file = onnx_export.export_module_onnx(net, tmp_path / "float.onnx", (1, 3, 64, 96), {})

    def ops(path) -> Counter:
        return Counter(n.op_type for n in onnx.load(path).graph.node)

    assert ops(lean) == ops(full) and ops(lean)["QuantizeLinear"] > 0
    x = calib_tensors(1, seed=5)[0]
    assert all(np.array_equal(a, b) for a, b in zip(run(lean, x), run(full, x)))
    assert "BatchNormalization" not in ops(float_file)
