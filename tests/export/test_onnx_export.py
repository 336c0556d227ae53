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
