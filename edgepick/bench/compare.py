"""int8 against fp32 on the same scenes, and clutter-removal rounds, for `bench --cell` (Table 5.6).

The thesis's claim is that int8 picks as well as fp32. Two success rates side by side cannot say
so: each carries its own uncertainty, most of which the two share, since both models meet the same
scenes. Here each int8 row is compared with the fp32 row on those scenes, pair by pair (single
scenes: the same cycle; rounds: the same round, edgepick.intervals.clustered_difference), and the
interval of the difference is read against a stated margin: within it, outside it, or undecided.
"""

from __future__ import annotations

from dataclasses import dataclass

from edgepick.bench.report import markdown
from edgepick.intervals import clustered_difference, equivalence, paired_outcomes, rounded
from edgepick.robot.cycle import CycleResult

VERDICTS = {"verdict": "geometric", "physics": "physics"}


@dataclass
class Measured:
    """A row's cycles as they ran: its results, its rounds' `describe()` (None: single scenes), and
    the model's precision (fp32, int8, or "-" for the true labels)."""

    mode: str
    precision: str
    results: list[CycleResult]
    rounds: list[dict] | None = None


def _succeeded(r: CycleResult, key: str) -> bool:
    """Whether R's verdict KEY ("verdict" or "physics") is a success (False where it has none)."""
    v = r.judged(key)
    return v is not None and v.success


def _per_round(m: Measured, key: str) -> list[tuple[int, int]]:
    """(successes, picks) of each round of M under the verdict KEY."""
    out = []
    for d in m.rounds or []:
        these = [r for r in m.results if r.round is not None and r.round["round"] == d["round"]
                 and r.judged(key) is not None]
        out.append((sum(_succeeded(r, key) for r in these), len(these)))
    return out


def compare(rows: list[Measured], margin: float) -> list[dict]:
    """Each int8 row against the (first) fp32 row, per verdict both have: the difference of their
    success rates (int8 minus fp32), its paired 95% interval and what it says against +-MARGIN; with
    rounds, their clearance too. Empty without an fp32 row."""
    base = next((m for m in rows if m.precision == "fp32"), None)
    if base is None:
        return []
    out = []
    for m in rows:
        if m.precision != "int8":
            continue
        for key, name in VERDICTS.items():
            if not any(r.judged(key) for r in m.results) or not any(r.judged(key) for r in base.results):
                continue
            if m.rounds is not None:
                found = clustered_difference(_per_round(m, key), _per_round(base, key))
                pairs = len(m.rounds)
            else:
                found = paired_outcomes([_succeeded(r, key) for r in m.results], [_succeeded(r, key) for r in base.results])
                pairs = len(m.results)
            out.append(_entry(m, base, "grasp success", name, found, pairs, margin))
        if m.rounds is not None:
            found = clustered_difference([(d["removed"], d["parts"]) for d in m.rounds],
                                         [(d["removed"], d["parts"]) for d in base.rounds or []])
            out.append(_entry(m, base, "clearance", "physics" if any(r.physics is not None for r in m.results)
                              else "geometric", found, len(m.rounds), margin))
    return out


def _entry(m: Measured, base: Measured, rate: str, verdict: str, found, pairs: int, margin: float) -> dict:
    d, ci = found if found is not None else (None, None)
    return {"mode": m.mode, "against": base.mode, "rate": rate, "verdict": verdict,
            "paired_by": "round" if m.rounds is not None else "scene", "pairs": pairs,
            "difference": None if d is None else round(d, 4), "ci95": rounded(ci), "margin": margin,
            "equivalence": None if ci is None else equivalence(ci, margin)}


STATEMENT = {"within": "equivalent: within", "outside": "different: beyond", "undecided": "undecided at"}


def compare_section(entries: list[dict]) -> list[str]:
    """Markdown: each int8 row's difference from fp32 with its interval and the statement it supports."""
    if not entries:
        return []

    def pp(v: float) -> str:
        return f"{100 * v:+.2f}"

    body = [[e["mode"], e["against"], e["rate"], e["verdict"], f"{e['pairs']} {e['paired_by']}s",
             "-" if e["difference"] is None else pp(e["difference"]),
             "-" if e["ci95"] is None else f"[{pp(e['ci95'][0])}, {pp(e['ci95'][1])}]",
             "-" if e["equivalence"] is None else f"{STATEMENT[e['equivalence']]} +-{100 * e['margin']:g} pp"]
            for e in entries]
    return ["", "## int8 against fp32 on the same scenes", "",
            "The difference of the rates (int8 minus fp32, percentage points) with its paired 95% interval "
            "(docs/contracts.md#clutter-removal-rounds): equivalent when the whole interval lies within the margin.", "",
            markdown(["Mode", "against", "Rate", "Verdict", "Pairs", "Difference (pp)", "95% CI (pp)", "Statement"], body)]


def _ci(d: dict, key: str) -> str:
    ci = d.get(key)
    return "" if ci is None else f" [{100 * ci[0]:.1f}, {100 * ci[1]:.1f}]"


def rounds_section(modes: list[str], summaries: list[dict], lights: list[str]) -> list[str]:
    """Markdown: each row's clutter-removal rounds summed (success, clearance, picks per part, failures,
    how the rounds ended, time per pick) and per light condition."""
    def kinds(counts: dict) -> str:
        return ", ".join(f"{k} {v}" for k, v in counts.items()) or "-"

    def rate(d: dict, what: str, num: str, den: str) -> str:
        value = d.get(f"{what}_rate" if what == "success" else what)
        return "-" if value is None else f"{100 * value:.1f} ({d[num]}/{d[den]}){_ci(d, f'{what}_ci95')}"

    body = [[mode, str(s["rounds"]), str(s["parts"]), str(s["picks"]), rate(s, "success", "success", "picks"),
             rate(s, "clearance", "removed", "parts"), "-" if s["picks_per_part"] is None else f"{s['picks_per_part']:.2f}",
             str(s["fell"]), kinds(s["failures"]), kinds(s["ended"]),
             "-" if s["time_per_pick_s"] is None else f"{s['time_per_pick_s']:.1f}"] for mode, s in zip(modes, summaries)]
    per_light = [[mode, *("-" if light not in s["by_lighting"] else
                          f"{rate(s['by_lighting'][light], 'success', 'success', 'picks')} / "
                          f"{rate(s['by_lighting'][light], 'clearance', 'removed', 'parts')}" for light in lights)]
                 for mode, s in zip(modes, summaries)]
    verdict = summaries[0]["verdict"] if summaries else "geometric"
    return ["", "## Clutter removal", "",
            f"Rounds laid out once and picked from until the table is empty, two failures in a row or the cap (a "
            f"part leaves the table when the {verdict} verdict passes its grasp); grasp success over the picks and "
            "clearance over the parts laid out, each with its 95% Wilson interval; parts that left the tray with "
            "another (carried along, pushed off) are not cleared; time per pick: frame -> plan and the arm's "
            "simulated motion:", "",
            markdown(["Mode", "Rounds", "Parts", "Picks", "Grasp success (%)", "Clearance (%)", "Picks per part",
                      "Left the tray", "Failures", "Ended", "Time per pick (s)"], body), "",
            "Grasp success / clearance (%) per light condition:", "",
            markdown(["Mode", *lights], per_light)]
