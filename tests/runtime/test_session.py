"""The runtime session: the checks of docs/contracts.md#onnx-model and frame resizing, on small ONNX files
built with onnx.helper."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

onnx = pytest.importorskip("onnx")
from onnx import TensorProto, helper  # noqa: E402

from edgepick.errors import ConfigError  # noqa: E402
from edgepick.geometry import Size  # noqa: E402
from edgepick.runtime.session import ModelError, Segmenter  # noqa: E402


def red_channel_model(path: Path, h: int = 8, w: int = 12, in_type=TensorProto.UINT8, meta: dict | None = None,
                      divide: int = 1) -> Path:
    """A contract model whose labels are the image's red channel (integer-divided by `divide`),
    so the expected output is known."""
    starts = helper.make_tensor("s", TensorProto.INT64, [1], [0])
    ends = helper.make_tensor("e", TensorProto.INT64, [1], [1])
    axes = helper.make_tensor("a", TensorProto.INT64, [1], [3])
    nodes = [helper.make_node("Slice", ["image", "s", "e", "a"], ["red"]),
             helper.make_node("Squeeze", ["red", "a"], ["labels0"]),
             helper.make_node("Cast", ["labels0"], ["labels1"], to=TensorProto.UINT8),
             helper.make_node("Div", ["labels1", "d"], ["labels"])]
    graph = helper.make_graph(nodes, "red", [helper.make_tensor_value_info("image", in_type, [1, h, w, 3])],
                              [helper.make_tensor_value_info("labels", TensorProto.UINT8, [1, h, w])],
                              initializer=[starts, ends, axes, helper.make_tensor("d", TensorProto.UINT8, [], [divide])])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    props = {"edgepick.classes": json.dumps(["background", "a", "b"]), "edgepick.input_size": json.dumps([h, w]),
             "edgepick.colorspace": "rgb", "edgepick.precision": "fp32"} if meta is None else meta
    for k, v in props.items():
        entry = model.metadata_props.add()
        entry.key, entry.value = k, v
    onnx.save(model, path)
    return path


def test_labels_come_back_at_the_frame_size(tmp_path):
    seg = Segmenter(red_channel_model(tmp_path / "m.onnx"), threads=1)
    assert seg.info.classes == ["background", "a", "b"] and seg.info.input_size == Size(12, 8)
    frame = np.zeros((16, 24, 3), np.uint8)
    frame[:8, :12, 0] = 2  # top-left quarter is class 2
    labels = seg.labels(frame)
    assert labels.shape == (16, 24) and labels.dtype == np.uint8
    assert (labels[:8, :12] == 2).all() and (labels[8:, :] == 0).all() and (labels[:, 12:] == 0).all()


def test_a_class_id_beyond_the_models_classes_is_refused_not_dropped(tmp_path):
    """A model whose metadata names fewer classes than its output gives: one line naming the id, never
    labels whose extra regions the grasp step would skip without a word."""
    seg = Segmenter(red_channel_model(tmp_path / "m.onnx"), threads=1)  # three classes: ids 0 to 2
    frame = np.zeros((8, 12, 3), np.uint8)
    frame[2:4, 2:4, 0] = 2
    assert seg.labels(frame).max() == 2
    frame[5, 5, 0] = 255
    with pytest.raises(ModelError, match=r"gave class id 255, but its edgepick.classes names 3 classes \(ids 0 to 2\)"):
        seg.labels(frame)


@pytest.mark.parametrize("case", ["no_meta", "float_input", "missing_file", "not_onnx"])
def test_models_outside_the_contract_are_refused(tmp_path, case):
    path = tmp_path / "m.onnx"
    if case == "no_meta":
        red_channel_model(path, meta={})
    elif case == "float_input":
        red_channel_model(path, in_type=TensorProto.FLOAT)
    elif case == "not_onnx":
        path.write_bytes(b"not a model")
    with pytest.raises(ModelError) as err:
        Segmenter(path)
    assert "\n" not in str(err.value)



def test_openvino_engine_gives_the_same_labels(tmp_path):
    pytest.importorskip("openvino")
    path = red_channel_model(tmp_path / "m.onnx", 24, 32)
    frame = np.random.default_rng(0).integers(0, 3, (48, 64, 3)).astype(np.uint8)
    ort_labels = Segmenter(path, threads=1).labels(frame)
    ov = Segmenter(path, threads=1, engine="openvino")
    assert ov.session is None and np.array_equal(ov.labels(frame), ort_labels)


def test_unknown_engine_is_refused(tmp_path):
    with pytest.raises(ConfigError, match="engine='tensorrt': must be one of onnxruntime, openvino, auto"):
        Segmenter(red_channel_model(tmp_path / "m.onnx"), engine="tensorrt")


def test_engine_auto_measures_once_per_model_and_caches(tmp_path, monkeypatch):
    """--engine auto: the faster engine for this model, threads and CPU, measured once and read back after;
    onnxruntime (and no cache) where OpenVINO is not installed."""
    import importlib.util

    from edgepick.runtime import session
    from tests.runtime.test_pipeline import red_model

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    model = red_model(tmp_path / "m.onnx")
    cache = tmp_path / "cache" / "edgepick" / "engines.json"
    real_find_spec = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "openvino" else real_find_spec(name, *a))
    seg = session.Segmenter(model, engine="auto")
    assert seg.engine == "onnxruntime" and "not installed" in seg.engine_choice["why"] and not cache.exists()
    monkeypatch.setattr(importlib.util, "find_spec", real_find_spec)
    pytest.importorskip("openvino")
    first = session.Segmenter(model, engine="auto")
    (record,) = json.loads(cache.read_text()).values()
    assert first.engine == record["engine"] == min(record["p50_ms"], key=record["p50_ms"].get)
    assert set(record["p50_ms"]) == {"onnxruntime", "openvino"}
    monkeypatch.setattr(session, "median_ms", lambda *a, **k: pytest.fail("measured again"))
    again = session.Segmenter(model, engine="auto")
    assert again.engine == first.engine and again.labels(np.zeros((240, 320, 3), np.uint8)).shape == (240, 320)
    with pytest.raises(ConfigError, match="engine='fastest': must be one of"):
        session.Segmenter(model, engine="fastest")


def compile_spy(monkeypatch) -> list:
    """Records the config and the compiled model of every OpenVINO CPU compile from here on."""
    ov = pytest.importorskip("openvino")
    compiled = []
    real = ov.Core.compile_model

    def spy(self, model, device=None, config=None, *args, **kwargs):
        compiled.append((config or {}, real(self, model, device, config, *args, **kwargs)))
        return compiled[-1][1]

    monkeypatch.setattr(ov.Core, "compile_model", spy)
    return compiled


@pytest.mark.parametrize("precision", ["fp32", "int8"])
def test_openvino_engine_runs_float_parts_in_f32(tmp_path, monkeypatch, precision):
    """OpenVINO runs float models in bf16 on CPUs with AMX or avx512_bf16 unless told f32: the runtime
    tells it, for fp32 models and for the float parts of int8 ones."""
    import openvino as ov

    compiled = compile_spy(monkeypatch)
    meta = {"edgepick.classes": json.dumps(["background", "a", "b"]), "edgepick.input_size": json.dumps([8, 12]),
            "edgepick.colorspace": "rgb", "edgepick.precision": precision}
    Segmenter(red_channel_model(tmp_path / "m.onnx", meta=meta), threads=1, engine="openvino")
    ((config, model),) = compiled
    assert config["INFERENCE_PRECISION_HINT"] == "f32"
    assert model.get_property("INFERENCE_PRECISION_HINT") == ov.Type.f32


def test_alternating_blocks_wait_before_each_block_when_several_models_are_timed():
    """Each block of an alternating timing starts SWITCH_PAUSE_S after the previous model's last
    call, so that no timed call shares the cores with another session's spinning threads; one model
    alone is timed without pauses."""
    import time

    from edgepick.runtime.session import SWITCH_PAUSE_S, interleaved_times, median_ms

    log: list[tuple[str, float]] = []
    calls = [lambda i, name=name: log.append((name, time.perf_counter())) for name in "ab"]
    times = interleaved_times(calls, runs=4, block=2)
    assert [len(t) for t in times] == [4, 4]
    switches = [(t1 - t0) for (a, t0), (b, t1) in zip(log, log[1:]) if a != b]
    assert len(switches) == 3 and min(switches) >= SWITCH_PAUSE_S
    log.clear()
    t0 = time.perf_counter()
    median_ms({"a": lambda x: log.append(("a", time.perf_counter()))}, np.zeros(1), timed=10, block=5)
    assert time.perf_counter() - t0 < SWITCH_PAUSE_S and len(log) == 3 + 2 + 10
