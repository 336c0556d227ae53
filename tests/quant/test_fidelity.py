"""How close int8 outputs stay to fp32's, for any output (quant/fidelity.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from onnx import helper

from edgepick.errors import ParameterError
from edgepick.quant.fidelity import (
    OutputFidelity,
    Task,
    TaskKind,
    balanced_error,
    guess_task,
    parse_tasks,
    probability_outputs,
)
from edgepick.quant.onnx.static import quantize_onnx_static
from tests.quant.onnx_models import box_table_model, detector_head_model, helper_model


def test_tasks_parse_and_refuse_in_one_line():
    assert Task.parse("labels") == Task(TaskKind.LABELS)
    assert Task.parse("threshold:0.3") == Task(TaskKind.THRESHOLD, 0.3) and str(Task.parse("threshold")) == "threshold:0.5"
    assert Task.parse(" top1 ").kind == TaskKind.TOP1 and Task.parse("raw").decide(np.ones(3)) is None
    assert Task.parse("boxes") == Task(TaskKind.BOXES, 0.25) and str(Task.parse("boxes-obj:0.4")) == "boxes-obj:0.4"
    for bad, message in (("boxes2", "not one of"), ("labels:3", "only threshold, boxes, boxes-obj take"),
                         ("threshold:x", "must be a number"), ("threshold:nan", "finite"), ("boxes:inf", "finite")):
        with pytest.raises(ParameterError, match=f"^task=.*{message}"):
            Task.parse(bad)


def test_task_texts_give_one_task_or_one_per_output_and_refuse_a_mix():
    assert parse_tasks([]) is None and parse_tasks(["ctc"]) == Task(TaskKind.CTC)
    assert parse_tasks(["537=threshold:0.2", "538=raw"]) == {"537": Task(TaskKind.THRESHOLD, 0.2), "538": Task(TaskKind.RAW)}
    assert parse_tasks(["a=b=raw"]) == {"a=b": Task(TaskKind.RAW)}  # the task is after the last "="
    with pytest.raises(ParameterError, match="^task='labels': one task for all outputs is given twice"):
        parse_tasks(["raw", "labels"])
    with pytest.raises(ParameterError, match="^task: give one task for all outputs, or OUTPUT=TASK for each, not both"):
        parse_tasks(["raw", "out=labels"])
    with pytest.raises(ParameterError, match="^task='out=box'"):
        parse_tasks(["out=box"])


def test_each_output_shape_gets_the_task_it_most_likely_has():
    assert guess_task((1, 5, 32, 32), False) == Task(TaskKind.LABELS)
    assert guess_task((1, 32, 32, 5), False, nhwc=True) == Task(TaskKind.LABELS)
    assert guess_task((1, 1, 32, 32), True) == Task(TaskKind.THRESHOLD, 0.5)
    assert guess_task((1, 1, 32, 32), False) == Task(TaskKind.THRESHOLD, 0.0)
    assert guess_task((1, 4), "Softmax") == Task(TaskKind.TOP1) and guess_task((1, 80, 4), "Softmax").kind == "top1"
    assert guess_task((1, 8400, 80), "Sigmoid") == Task(TaskKind.THRESHOLD, 0.5)  # multi-label scores
    # a detector's raw rows (boxes in pixels, scores) decide nothing by their sign
    assert guess_task((1, 8400, 85), False) == Task(TaskKind.RAW) and guess_task((1, 4), False) == Task(TaskKind.RAW)


def test_sqnr_cosine_and_agreement_against_numpy():
    rng = np.random.default_rng(0)
    ref = rng.normal(0, 1, (2, 3, 8, 8)).astype(np.float32)
    noisy = ref + rng.normal(0, 0.1, ref.shape).astype(np.float32)
    f = OutputFidelity(Task(TaskKind.LABELS))
    f.add(ref[:1], noisy[:1])
    f.add(ref[1:], noisy[1:])
    a, b = ref.astype(np.float64).ravel(), noisy.astype(np.float64).ravel()
    assert f.sqnr_db == pytest.approx(10 * math.log10((a @ a) / ((a - b) @ (a - b))))
    assert f.cosine == pytest.approx((a @ b) / math.sqrt((a @ a) * (b @ b)))
    assert f.agreement == pytest.approx(float((ref.argmax(1) == noisy.argmax(1)).mean()), abs=1e-5)
    exact = OutputFidelity(Task(TaskKind.RAW))
    exact.add(ref, ref)
    assert exact.to_dict() == {"task": "raw", "sqnr_db": None, "cosine": 1.0, "agreement": None}


def test_a_small_score_channel_counts_as_much_as_box_coordinates():
    rng = np.random.default_rng(1)
    rows = np.concatenate([rng.uniform(0, 640, (1, 100, 4)), rng.uniform(0, 1, (1, 100, 1))], 2)
    boxes_off = rows.copy()
    boxes_off[..., :4] += 1.0  # a pixel off on every box
    scores_off = rows.copy()
    scores_off[..., 4] *= 0.5  # every score halved
    plain = [float(((rows - t) ** 2).sum() / (rows**2).sum()) for t in (boxes_off, scores_off)]
    assert plain[1] < plain[0]  # plain relative error hides the halved scores behind the pixels
    assert balanced_error([rows], [scores_off]) > 10 * balanced_error([rows], [boxes_off])


def test_a_sigmoid_behind_reshape_and_transpose_is_still_a_probability(tmp_path):
    w = np.random.default_rng(3).normal(0, 1, (2, 3, 1, 1)).astype(np.float32)
    nodes = [helper.make_node("Conv", ["input", "w"], ["logit"], name="conv"),
             helper.make_node("Sigmoid", ["logit"], ["p"], name="sigmoid"),
             helper.make_node("Reshape", ["p", "shape"], ["flat"], name="reshape"),
             helper.make_node("Transpose", ["flat"], ["scores"], perm=[0, 2, 1], name="transpose")]
    path = helper_model(nodes, [("input", [1, 3, 16, 16])], [("scores", [1, 256, 2])],
                        {"w": w, "shape": np.array([1, 2, -1], np.int64)}, tmp_path / "m.onnx")
    import onnx

    assert probability_outputs(onnx.load(str(path))) == {"scores": "Sigmoid"}
    assert probability_outputs(onnx.load(str(detector_head_model(tmp_path / "d.onnx")))) == {"rows": None}
    xs = [np.random.default_rng(k).normal(0, 1, (1, 3, 16, 16)).astype(np.float32) for k in range(6)]
    result = quantize_onnx_static(path, xs, tmp_path / "int8.onnx", progress=False)
    assert result.fidelity["scores"]["task"] == "threshold:0.5"  # [1, rows, 2] sigmoid scores, each decided
    assert result.agreement_vs_fp32["scores"] >= 0.95 and result.fidelity["scores"]["cosine"] > 0.99


def test_a_box_task_scores_the_f1_of_the_boxes_found_again():
    rng = np.random.default_rng(4)
    ref = np.zeros((1, 40, 6), np.float32)
    ref[0, :, :2] = rng.uniform(0, 600, (40, 2))
    ref[0, :, 2:4] = 20.0
    ref[0, :10, 4] = 0.9  # ten boxes of class 0, the rest score 0
    test = ref.copy()
    test[0, :3, 4] = 0.1  # three lost
    test[0, 20:22, 5] = 0.8  # two more, of class 1
    found = OutputFidelity(Task.parse("boxes"))
    found.add(ref, test)
    assert found.same == 2 * 7 and found.decided == 10 + 9
    assert found.agreement == pytest.approx(14 / 19, abs=1e-5)
    with pytest.raises(ParameterError, match="^task='boxes:0.25': output scores of shape .1, 2, 8, 8. is no box table"):
        Task.parse("boxes").check_shape((1, 2, 8, 8), "scores")
    Task.parse("boxes-obj").check_shape((1, 0, 85), "rows")  # rows not known before a run: a table still


def test_a_threshold_task_scores_the_f1_of_the_cells_above_it():
    ref = np.full((1, 1000, 3), 0.01, np.float32)  # a detector's score map: nearly every cell a negative
    ref[0, :10, 0] = 0.9
    test = ref.copy()
    test[0, :4, 0] = 0.3  # four of ten detections lost
    test[0, 500, 1] = 0.7  # one cell more
    found = OutputFidelity(Task(TaskKind.THRESHOLD, 0.5))
    found.add(ref, test)
    assert found.same == 2 * 6 and found.decided == 10 + 7
    assert found.agreement == pytest.approx(12 / 17, abs=1e-5)  # cell by cell it would read 99.8%
    quiet = OutputFidelity(Task(TaskKind.THRESHOLD, 0.5))
    quiet.add(ref * 0, test * 0)
    assert quiet.agreement is None  # no cell above T in either: nothing decided


def test_quantize_with_a_box_task_reports_the_f1_of_the_boxes(tmp_path):
    path = box_table_model(tmp_path / "m.onnx")
    xs = [np.random.default_rng(k).uniform(0, 1, (1, 3, 32, 32)).astype(np.float32) for k in range(8)]
    result = quantize_onnx_static(path, xs, tmp_path / "int8.onnx", progress=False, task=Task.parse("boxes"))
    assert result.fidelity["table"]["task"] == "boxes:0.25"
    assert 0.9 <= result.agreement_vs_fp32["table"] <= 1.0, result.fidelity


def test_a_rule_that_keeps_more_labels_ranks_first_whatever_its_error():
    """A labels output: the range rule that clips the few high logits a label turns on can have the
    smaller error over all logits; the labels decide, the error only breaks their ties."""
    from edgepick.quant.fidelity import RuleScore
    from edgepick.quant.ranges import RangeRule

    tight = RuleScore(RangeRule.parse("percentile 99.99"), error=0.006, changed=900, decided=100_000)
    wide = RuleScore(RangeRule.parse("percentile 99.999"), error=0.008, changed=600, decided=100_000)
    assert min([tight, wide], key=lambda s: s.rank) is wide
    assert wide.to_dict()["label_agreement"] == 0.994 and "label_agreement" not in RuleScore(wide.rule, 0.008).to_dict()
    tie = RuleScore(RangeRule.parse("mse"), error=0.007, changed=600, decided=100_000)
    assert min([wide, tie], key=lambda s: s.rank) is tie
    # without labels (a model whose outputs are not known to be labels) the error alone ranks
    assert min([RuleScore(tight.rule, 0.006), RuleScore(wide.rule, 0.008)], key=lambda s: s.rank).rule == tight.rule


def test_the_output_that_changes_the_largest_share_of_its_decisions_ranks_a_rule():
    """An ONNX model's outputs, each judged by its task: the one that changes the largest share of
    fp32's decisions speaks for the rule (a raw output decides nothing); the record names them decisions."""
    from edgepick.quant.fidelity import OutputFidelity, RuleScore, most_changed
    from edgepick.quant.ranges import RangeRule

    fidelity = {"mask": OutputFidelity(Task.parse("threshold:0.5"), same=990, decided=1000),
                "top": OutputFidelity(Task.parse("top1"), same=7, decided=8),
                "boxes": OutputFidelity(Task.parse("raw"), same=0, decided=0)}
    assert most_changed(fidelity) == (1, 8)
    assert most_changed({"boxes": fidelity["boxes"]}) == (None, 0)
    assert most_changed({"mask": OutputFidelity(Task.parse("threshold:0.5"))}) == (0, 0)  # nothing above T in either
    score = RuleScore(RangeRule.parse("mse"), 0.01, *most_changed(fidelity), decisions="decision")
    assert score.to_dict()["decision_agreement"] == 0.875 and score.rank == (0.125, 0.01)


def test_a_rule_that_changes_fewer_decisions_is_kept_over_the_closest_only_beyond_chance():
    """A face map's few cells on 8 held-out images change by a handful between rules, which says
    nothing: the closest outputs keep the choice; many decisions apart (a mask's pixels) the
    decisions win (McNemar's bound: the difference over the square root of the changes, above 2)."""
    from edgepick.quant.fidelity import RuleScore, beyond_chance, ranked_rule
    from edgepick.quant.ranges import RangeRule

    def score(rule: str, error: float, changed: int | None, decided: int) -> RuleScore:
        return RuleScore(RangeRule.parse(rule), error, changed, decided, decisions="decision")

    closest, fewer = score("percentile 99.99", 0.10, 9, 120), score("percentile 99.999", 0.12, 5, 120)
    assert not beyond_chance(fewer, closest) and ranked_rule([closest, fewer]) is closest
    closest, fewer = score("percentile 99.99", 0.10, 900, 100_000), score("mse", 0.12, 600, 100_000)
    assert beyond_chance(fewer, closest) and ranked_rule([closest, fewer]) is fewer
    raw = [score("minmax", 0.2, None, 0), score("entropy", 0.1, None, 0)]
    assert ranked_rule(raw) is raw[1]  # nothing decided: the closest

