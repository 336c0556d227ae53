"""QuantRecord: every pass's `edgepick.quant` entry, its keys in the order each kind of file has
always written them (docs/contracts.md#onnx-model), its values from the configs the pass was given."""

from __future__ import annotations

import json

from edgepick.quant.config import OnnxOptions, Pt2eOptions, PtqMethods, QatOptions, QuantConfig
from edgepick.quant.record import QuantRecord, RecordKind


def test_a_checkpoints_static_file_records_the_torch_graphs_placement_and_every_method():
    record = QuantRecord(RecordKind.STATIC, QuantConfig(keep_float=("classifier.4",)), 16, PtqMethods(),
                         pt2e=Pt2eOptions(), ranges={"rule": "mse"}, measured={"measured_images": 16}).to_dict()
    assert record == {"mode": "static", "qat_fraction": None, "calib_method": "auto", "calib_images": 16,
                      "percentile": 99.99, "weight_bits": "7", "hardswish_gate": True, "bias_correction": "empirical",
                      "equalize": False, "adaround": False, "adaround_budget_s": None, "placement": "all",
                      "target": "onnxruntime", "gelu": "float", "keep_float": ["classifier.4"], "skip": ["preprocess"],
                      "ranges": {"rule": "mse"}, "measured_images": 16}
    assert list(record) == list(json.loads(json.dumps(record)))


def test_the_qat_passes_record_their_options_and_hybrid_its_start():
    qat = QuantRecord(RecordKind.QAT, QuantConfig(weight_bits="8"), qat=QatOptions(), pt2e=Pt2eOptions(),
                      qat_fraction=1.0, calib_method="qat").to_dict()
    assert qat == {"mode": "qat", "qat_fraction": 1.0, "calib_method": "qat", "calib_images": None, "weight_bits": "8",
                   "weight_averaging": 0.01, "hardswish_gate": True, "keep_float": [], "skip": ["preprocess"]}
    hybrid = QuantRecord(RecordKind.HYBRID, QuantConfig(), 64, qat=QatOptions(freeze_at=0.5), pt2e=Pt2eOptions(),
                         qat_fraction=0.1, calib_method="qat from percentile 99.99",
                         hybrid={"carry_optimizer": True, "hold_ranges": True}).to_dict()
    assert list(hybrid)[-4:] == ["skip", "freeze_at", "carry_optimizer", "hold_ranges"]
    assert hybrid["freeze_at"] == 0.5 and hybrid["calib_images"] == 64 and hybrid["mode"] == "hybrid"


def test_a_foreign_models_file_records_its_source_and_adaround_budget_only_where_it_ran():
    onnx = QuantRecord(RecordKind.ONNX, QuantConfig(), 8, PtqMethods(), OnnxOptions(placement="convs"),
                       ranges={"rule": "minmax"}).to_dict()
    assert list(onnx) == ["mode", "source", "calib_method", "calib_images", "percentile", "weight_bits", "placement",
                          "gelu", "equalize", "bias_correction", "adaround", "adaround_if_far", "keep_float", "ranges"]
    assert onnx["source"] == "onnx" and onnx["placement"] == "convs" and onnx["adaround_if_far"] is True
    ran = QuantRecord(RecordKind.ONNX, QuantConfig(), 8, PtqMethods(adaround=True, adaround_budget_s=5.0),
                      OnnxOptions()).to_dict()
    assert ran["adaround_budget_s"] == 5.0
    tried = QuantRecord(RecordKind.ONNX, QuantConfig(), 8, PtqMethods(adaround_budget_s=7.0), OnnxOptions(),
                        measured={"adaround_first": {"kept": False}}).to_dict()
    assert tried["adaround"] is False and tried["adaround_budget_s"] == 7.0  # tried for a file far from fp32
    module = QuantRecord(RecordKind.MODULE, QuantConfig(), 4, PtqMethods(), ranges={}).to_dict()
    assert module["source"] == "module" and "placement" not in module and "hardswish_gate" not in module
