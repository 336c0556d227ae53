"""The shared math of static PTQ's methods (edgepick/quant/methods.py) not tested with a pass:
AdaRound's step plan, what a pass records of it, and its solver."""

from __future__ import annotations

import numpy as np

from edgepick.quant.methods import MAX_STEPS, MIN_STEPS, STEP_OVERHEAD, WORK, adaround_done, planned_steps, round_conv


def test_adaround_plans_the_most_steps_where_the_model_affords_them_and_fewer_on_a_larger_one():
    small = [10_000 + STEP_OVERHEAD] * 50
    assert planned_steps(small) == MAX_STEPS
    large = [int(WORK / MAX_STEPS)] * 4  # four times what MAX_STEPS affords
    assert planned_steps(large) == MAX_STEPS // 4
    assert planned_steps([int(WORK)]) == MIN_STEPS  # never fewer than the least that learns anything
    assert planned_steps(c for c in large) == MAX_STEPS // 4  # the passes give it a generator of costs


def test_a_pass_records_how_many_convs_kept_a_learnt_rounding_and_the_steps_per_conv():
    report = {"a": {"error_nearest": 2.0, "error_adaround": 1.0, "steps": 40},
              "b": {"error_nearest": 1.0, "error_adaround": 1.0, "steps": 90},
              "c": {"error_nearest": 3.0, "error_adaround": 0.5, "steps": 60}}
    assert adaround_done(report) == {"adaround_convs": 2, "adaround_steps": 60}
    assert adaround_done({}) == {"adaround_convs": 0, "adaround_steps": 0}


def test_the_solver_rounds_each_weight_down_or_up_and_lowers_the_output_error():
    width = 600
    rng = np.random.default_rng(1)
    w = rng.normal(0, 0.1, size=(16, width, 1, 1)).astype(np.float32)
    scale = np.abs(w).reshape(16, -1).max(axis=1) / 127
    x = rng.normal(size=(width, 2048)).astype(np.float32)
    target = w.reshape(16, -1) @ x
    codes, nearest, learnt, taken = round_conv(w, scale, -127, 127, np.zeros(16, np.float32), x, target, 1, 0.0,
                                               np.random.default_rng(2), steps=60)
    assert taken == 60 and learnt < nearest
    ratio = w / scale.reshape(-1, 1, 1, 1)
    assert np.all((codes == np.floor(ratio)) | (codes == np.floor(ratio) + 1))

