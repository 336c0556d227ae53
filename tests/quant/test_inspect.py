"""Per-layer drift (quantize inspect) and the accuracy-aware static pass, on the short test run."""

from __future__ import annotations

import json
import math

import pytest

torch = pytest.importorskip("torch")

from edgepick.quant.config import BiasCorrection, CalibMethod, PtqMethods, QuantConfig  # noqa: E402
from edgepick.quant.pt2e.images import folder_images, model_images  # noqa: E402
from edgepick.quant.pt2e.inspect import compare, float_graph, inspect, quantize_accuracy_aware  # noqa: E402
from edgepick.train.checkpoint import load_model  # noqa: E402
from tests.conftest import run_cli  # noqa: E402

pytestmark = pytest.mark.slow


def test_a_graph_compared_with_itself_has_no_drift(trained_run, small_data):
    model, ckpt = load_model(trained_run)
    size = ckpt.input_size
    gm = float_graph(model, size)
    report = compare(gm, gm, model_images(small_data, "val", 2, size))
    assert len(report["layers"]) > 50 and all(math.isinf(r["sqnr_db"]) for r in report["layers"])
    assert report["label_agreement"] == 1.0


def test_inspect_reports_every_conv_and_ranks_candidates(trained_run, small_data):
    report = inspect(trained_run, folder_images(small_data, "train", 8), folder_images(small_data, "val", 2),
                     progress=False)
    layers = report["layers"]
    assert len(layers) == 70 and layers[0]["layer"] == "backbone.0.0"
    assert layers[0]["sqnr_db"] > 20  # the first conv sees only its own rounding
    assert all(not math.isnan(r["sqnr_db"]) for r in layers)
    assert 0.5 < report["label_agreement"] <= 1.0 and math.isfinite(report["logits_sqnr_db"])
    assert set(report["ranked"]) <= {r["layer"] for r in layers} and len(report["ranked"]) >= 60


def test_accuracy_aware_static_keeps_the_worst_layers_float(trained_run, small_data, tmp_path, monkeypatch):
    import edgepick.quant.pt2e.inspect as module

    ranked_on = []  # the layer ranking runs only once a step misses the budget
    monkeypatch.setattr(module, "inspect", lambda *a, **k: ranked_on.append(1) or inspect(*a, **k))
    calib = folder_images(small_data, "train", 8)
    # the search is what this test is about, so each step quantizes with one fixed rule and no bias correction
    # (the default recipe's own steps are tested in test_passes.py)
    recipe = {"config": QuantConfig(calib_method=CalibMethod.PERCENTILE),
              "methods": PtqMethods(bias_correction=BiasCorrection.NONE)}
    result = quantize_accuracy_aware(trained_run, calib, small_data, tmp_path / "aa.onnx", max_drop_pp=0.0,
                                     max_float_layers=1, **recipe)
    steps = result.steps
    assert [len(s["keep_float"]) for s in steps] == list(range(len(steps))) and 1 <= len(steps) <= 2
    assert all(s["drop_pp"] > 0 for s in steps[:-1])  # it only goes on while over budget
    assert result.met == (steps[-1]["drop_pp"] <= 0) and (result.met or len(steps) == 2)
    assert (tmp_path / "aa.onnx").is_file() and result.chosen["drop_pp"] == min(s["drop_pp"] for s in steps)
    assert len(ranked_on) == (len(steps) > 1)
    easy = quantize_accuracy_aware(trained_run, iter(calib), small_data, tmp_path / "easy.onnx", max_drop_pp=100.0,
                                   **recipe)
    assert easy.met and len(easy.steps) == 1 and len(ranked_on) == (len(steps) > 1)  # met at once: no ranking


def test_inspect_cli_with_equalization_and_bias_correction(trained_run, small_data):
    proc = run_cli("quantize", "inspect", str(trained_run), "--data", str(small_data), "--calib-images", "8",
                   "--images", "2", "--top", "3", "--equalize", "--bias-correction", "empirical")
    assert proc.returncode == 0, proc.stderr
    report = json.loads(proc.stdout)
    assert "logits SQNR" in proc.stderr and "bias corr. gain dB" in proc.stderr and len(report["layers"]) == 70
    assert "CLE gain dB" in proc.stderr and report["equalized_pairs"] >= 10 and "label_agreement" in report["equalize"]
    cle = [r["equalize_gain_db"] for r in report["layers"] if r["equalize_gain_db"] is not None]
    assert len(cle) >= 60 and any(g != 0 for g in cle)
    assert report["bias_correction"]["method"] == "empirical" and report["bias_correction"]["images"] == 8
    gains = [r["bias_correction_gain_db"] for r in report["layers"] if r["bias_correction_gain_db"] is not None]
    assert len(gains) >= 60 and any(g != 0 for g in gains)
