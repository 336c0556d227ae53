"""Contract metadata: the training time of a run's best checkpoint is the whole run's."""

from __future__ import annotations

import json

import pytest

pytest.importorskip("torch")

from edgepick.export.onnx_export import run_train_time_s  # noqa: E402


def test_best_checkpoint_reports_the_whole_runs_training_time(tmp_path):
    (tmp_path / "metrics.json").write_text(json.dumps({"epochs": 100, "train_time_s": 228.4}))
    assert run_train_time_s({"path": str(tmp_path / "best.pt"), "train_time_s": 111.0}) == 228.4
    assert run_train_time_s({"path": str(tmp_path / "epoch_090.pt"), "train_time_s": 200.0}) == 200.0
    (tmp_path / "metrics.json").write_text("{broken")
    assert run_train_time_s({"path": str(tmp_path / "best.pt"), "train_time_s": 111.0}) == 111.0
