"""int8 against fp32 on the same scenes (bench/compare.py): paired by scene or by round, the interval of
the difference read against the margin, and the sections Table 5.6 gains."""

from __future__ import annotations

import math

from edgepick.bench.compare import Measured, compare, compare_section, rounds_section
from edgepick.intervals import clustered_difference, paired_difference
from edgepick.robot.cycle import CycleResult
from edgepick.robot.verdict import Verdict
from tests.conftest import make_grasp


def _judged(success: bool, physics: bool | None = None, **fields) -> CycleResult:
    """A planned cycle whose choice the geometric rule judged SUCCESS, and the physics check PHYSICS
    (None: it did not run)."""
    def verdict(ok: bool) -> Verdict:
        return Verdict(True) if ok else Verdict(False, "position")

    return CycleResult(1, "f", 1, {}, 1.0, "planned", chosen=make_grasp("box", (0.28, 0.0, 0.05, math.pi, 0.0, 0.0)),
                       verdict=verdict(success), undetected=0, physics=None if physics is None else verdict(physics),
                       **fields)


def _cycles(outcomes: list[bool], physics: list[bool] | None = None) -> list[CycleResult]:
    return [_judged(ok, p) for ok, p in zip(outcomes, physics or [None] * len(outcomes))]


def test_single_scenes_pair_cycle_by_cycle():
    """The Cavo et al. table as two models' cycles: 59 both pass, 6 only int8, 16 only fp32, 80 neither."""
    int8 = [True] * 59 + [True] * 6 + [False] * 16 + [False] * 80
    fp32 = [True] * 59 + [False] * 6 + [True] * 16 + [False] * 80
    rows = [Measured("true labels", "-", _cycles([True] * 161)), Measured("fp32 CPU", "fp32", _cycles(fp32)),
            Measured("static", "int8", _cycles(int8))]
    (entry,) = compare(rows, 0.01)
    d, (lo, hi) = paired_difference(59, 6, 16, 80)
    assert entry == {"mode": "static", "against": "fp32 CPU", "rate": "grasp success", "verdict": "geometric",
                     "paired_by": "scene", "pairs": 161, "difference": round(d, 4), "ci95": [round(lo, 4), round(hi, 4)],
                     "margin": 0.01, "equivalence": "undecided"}  # -11.9 to -0.5 pp: reaches inside -1 pp


def test_the_same_choices_on_many_scenes_are_equivalent_within_the_margin():
    same = [True] * 980 + [False] * 20
    rows = [Measured("fp32 CPU", "fp32", _cycles(same, same)), Measured("static", "int8", _cycles(same, same)),
            Measured("hybrid-QaT 5%", "int8", _cycles([True] * 950 + [False] * 50, same))]
    entries = compare(rows, 0.01)
    assert [(e["mode"], e["verdict"], e["equivalence"]) for e in entries] == [
        ("static", "geometric", "within"), ("static", "physics", "within"),
        ("hybrid-QaT 5%", "geometric", "outside"), ("hybrid-QaT 5%", "physics", "within")]
    assert compare(rows[1:], 0.01) == []  # no fp32 row: nothing to compare against
    text = "\n".join(compare_section(entries))
    assert "equivalent: within +-1 pp" in text and "different: beyond +-1 pp" in text and "1000 scenes" in text


def _round_results(per_round: list[tuple[int, int]]) -> tuple[list[CycleResult], list[dict]]:
    results: list[CycleResult] = []
    rounds = []
    for k, (won, picks) in enumerate(per_round, start=1):
        results += [_judged(i < won, round={"round": k}) for i in range(picks)]
        rounds.append({"round": k, "parts": picks + 1, "removed": won})
    return results, rounds


def test_rounds_pair_round_by_round_with_clearance():
    a, b = [(7, 7), (5, 6), (9, 10), (4, 4)], [(6, 7), (5, 7), (8, 10), (4, 4)]
    rows = [Measured("fp32 CPU", "fp32", *_round_results(b)), Measured("static", "int8", *_round_results(a))]
    success, clearance = compare(rows, 0.01)
    d, (lo, hi) = clustered_difference(a, b)
    assert success["paired_by"] == "round" and success["pairs"] == 4
    assert (success["difference"], success["ci95"]) == (round(d, 4), [round(lo, 4), round(hi, 4)])
    d, (lo, hi) = clustered_difference([(7, 8), (5, 7), (9, 11), (4, 5)], [(6, 8), (5, 8), (8, 11), (4, 5)])
    assert clearance["rate"] == "clearance" and clearance["ci95"] == [round(lo, 4), round(hi, 4)]


def test_rounds_section_shows_rates_with_their_intervals():
    summary = {"rounds": 2, "parts": 13, "picks": 14, "success": 12, "success_rate": 0.8571,
               "success_ci95": [0.6006, 0.9599], "removed": 12, "clearance": 0.9231, "clearance_ci95": [0.6669, 0.9863],
               "picks_per_part": 1.167, "fell": 1, "failures": {"blocked": 2}, "ended": {"cleared": 2},
               "time_per_pick_s": 7.2, "verdict": "physics",
               "by_lighting": {"single": {"success": 12, "picks": 14, "success_rate": 0.8571,
                                          "success_ci95": [0.6006, 0.9599], "removed": 12, "parts": 13,
                                          "clearance": 0.9231, "clearance_ci95": [0.6669, 0.9863]}}}
    text = "\n".join(rounds_section(["static"], [summary], ["single", "hazard"]))
    assert "| static | 2 | 13 | 14 | 85.7 (12/14) [60.1, 96.0] | 92.3 (12/13) [66.7, 98.6] | 1.17 | 1 | blocked 2 |" in text
    assert "| static | 85.7 (12/14) [60.1, 96.0] / 92.3 (12/13) [66.7, 98.6] | - |" in text
