"""`edgepick bench --cell N`: thesis Table 5.6 with its grasp success column, measured in the
closed loop. Each model runs N executions of the whole pick cycle in the synthetic cell (camera
0.7 m above the table, SimRobot, the same N seeded scenes for every model), judged per cycle by
robot/verdict.py and, with --verdict physics|both, by the physics check (sim/physics.py); a first
row runs the same cycles on the scenes' true labels, the grasp step's own ceiling without a
model. Success is also reported per light condition of the scenes (thesis Table 5.3)."""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, replace
from itertools import cycle
from pathlib import Path

import cv2
import numpy as np
import onnxruntime as ort

from edgepick.bench.compare import Measured, compare, compare_section, rounds_section
from edgepick.bench.measure import mode_label
from edgepick.bench.report import draw_axes, markdown
from edgepick.data.render import CLASSES, LIGHTINGS
from edgepick.errors import ParameterError
from edgepick.intervals import rounded, wilson
from edgepick.machine import machine_line
from edgepick.robot.clearance import HandShape
from edgepick.robot.cycle import CycleResult, verdicts
from edgepick.robot.grippers import DigitalGripper
from edgepick.robot.loop import Cell, run_cycles
from edgepick.robot.pick import CommandLog, PickConfig
from edgepick.robot.verdict import VerdictRule, summarize
from edgepick.runtime.engine import Engine
from edgepick.runtime.pipeline import Pipeline
from edgepick.runtime.session import Segmenter, check_model
from edgepick.sim.camera import SynthCamera
from edgepick.sim.oracle import TruthPipeline
from edgepick.sim.robot import SimRobot

HEADER = ["Mode", "Pipeline mean [std] (ms)", "p50 (ms)", "p95 (ms)", "Size (MB)", "Grasp success (%)",
          "of reachable (%)", "Failures"]
MOUNT_M = 0.7


@dataclass
class CellRow:
    mode: str
    model: str
    cycles: int
    mean_ms: float
    std_ms: float
    p50_ms: float
    p95_ms: float
    size_mb: float | None
    success: int
    success_rate: float
    success_rate_reachable: float | None
    failures: dict[str, int] = field(default_factory=dict)
    physics: dict | None = None  # the physics check: success, executions, success_rate, failures, ms_p50
    disagreements: dict[str, dict[str, int]] = field(default_factory=dict)  # class -> which rule alone passed it
    by_lighting: dict[str, dict] = field(default_factory=dict)  # light condition -> executions, success, ...
    success_ci95: list[float] | None = None  # the 95% Wilson intervals of success_rate and success_rate_reachable
    success_reachable_ci95: list[float] | None = None
    rounds: dict | None = None  # bench --cell --rounds: sim/clutter.py's round_summary of the row's rounds


def cell_row(mode: str, model: str, pipeline: Pipeline, cycles: int, seed: int, size_mb: float | None,
             verdict: VerdictRule = VerdictRule.GEOMETRIC, physics_config=None) -> CellRow:
    """CYCLES executions of the pick loop with PIPELINE on the cell's scenes of SEED (PHYSICS_CONFIG:
    the simulated grippers, sim/physics.py's PhysicsConfig)."""
    return measure_row(mode, model, pipeline, cycles, seed, size_mb, verdict, physics_config)[0]


def measure_row(mode: str, model: str, pipeline: Pipeline, cycles: int, seed: int, size_mb: float | None,
                verdict: VerdictRule = VerdictRule.GEOMETRIC, physics_config=None, rounds: int | None = None,
                round_config=None, hand: HandShape | None = None) -> tuple[CellRow, list[CycleResult], list[dict] | None]:
    """cell_row, with the cycles' results; with ROUNDS, that many clutter-removal rounds (sim/clutter.py,
    ROUND_CONFIG) in place of CYCLES single scenes, and the rounds' `describe()`. HAND: the hand the
    planner checks and opens (robot/clearance.py; its stroke is the physics check's)."""
    camera = SynthCamera(640, 480, seed=seed, mount_height_m=MOUNT_M)
    truth = camera.calibration()
    robot = SimRobot()
    physics = None
    # the thesis's Table 5.6 (the geometric rule alone) judges the choice as the thesis made it; with
    # the physics check the planner also checks the hand it simulates (robot/clearance.py)
    pick = PickConfig(hand=None)
    if verdict != VerdictRule.GEOMETRIC:
        from edgepick.sim.physics import PhysicsConfig, physics_judge

        physics_config = physics_config or PhysicsConfig()
        pick = PickConfig(hand=replace(hand or HandShape(), jaw_opening_m=physics_config.jaw_stroke_m))
        physics = physics_judge(truth, pick, physics_config)
    described = None
    results: list[CycleResult] = []
    with camera, robot:
        if rounds is None:
            results = run_cycles(Cell(camera, pipeline, robot, DigitalGripper(robot, 0), CommandLog(None), truth,
                                      physics=physics), cfg=pick, cycles=cycles, echo=lambda line: None)
        else:
            from edgepick.sim.clutter import run_rounds

            described = run_rounds(pipeline, robot, DigitalGripper(robot, 0), rounds=rounds, pick=pick,
                                   log=CommandLog(None), seed=seed, cfg=round_config, physics=physics_config,
                                   judge=physics is not None, echo=lambda line: None, done=results)
    times = np.array([r.plan_ms for r in results])  # frame -> labels -> records -> the checked plan
    summary = summarize(verdicts(results))
    row = CellRow(mode, model, len(results), round(float(times.mean()), 2), round(float(times.std()), 2),
                  round(float(np.median(times)), 2), round(float(np.percentile(times, 95)), 2), size_mb,
                  summary["success"], summary["success_rate"], summary["success_rate_reachable"], summary["failures"],
                  physics_summary(results) if physics else None, disagreements(results) if physics else {},
                  by_lighting(results), summary["success_ci95"], summary["success_reachable_ci95"])
    if described is not None:
        from edgepick.sim.clutter import round_summary

        row.rounds = round_summary(described, results)
    return row, results, described


def physics_summary(results: list[CycleResult]) -> dict:
    """The physics check over the judged cycles, with its time per check (p50 of those it simulated)."""
    judged = verdicts(results, "physics")
    times = [p.ms for p in judged if p.ms]
    s = summarize(judged)
    standing = len(judged) - s["failures"].get("unsettled", 0)  # the scenes that stand as rendered
    return {"success": s["success"], "executions": len(judged), "success_rate": s["success_rate"],
            "success_ci95": s["success_ci95"],
            "success_rate_standing": round(s["success"] / standing, 4) if standing else None,
            "success_standing_ci95": rounded(wilson(s["success"], standing)),
            "failures": s["failures"], "ms_p50": round(float(np.median(times)), 1) if times else None}


def disagreements(results: list[CycleResult]) -> dict[str, dict[str, int]]:
    """Per class of the chosen target: cycles only the geometric rule passed, and only physics."""
    out: dict[str, dict[str, int]] = {}
    for r in results:
        if r.physics is not None and r.verdict is not None and r.verdict.success != r.physics.success:
            side = "geometric only" if r.verdict.success else "physics only"
            counts = out.setdefault(r.target or "-", {"geometric only": 0, "physics only": 0})
            counts[side] += 1
    return out


def by_lighting(results: list[CycleResult]) -> dict[str, dict]:
    """Success per light condition of the scenes (thesis Table 5.3): executions, success, rate,
    failures, the objects no grasp record found (robot/verdict.py undetected), and the physics
    check's success where it ran."""
    def light_of(r: CycleResult) -> str | None:
        return (r.scene or {}).get("lighting")

    out: dict[str, dict] = {}
    judged = [r for r in results if r.verdict is not None]
    for light in dict.fromkeys(light_of(r) for r in judged):
        if light is None:
            continue
        these = [r for r in judged if light_of(r) == light]
        s = summarize(verdicts(these))
        out[light] = {"executions": len(these), "success": s["success"], "success_rate": s["success_rate"],
                      "success_ci95": s["success_ci95"], "failures": s["failures"],
                      "undetected": sum(r.undetected or 0 for r in these)}
        if any(r.physics is not None for r in these):
            p = summarize(verdicts(these, "physics"))
            out[light].update(physics_success=p["success"], physics_success_rate=p["success_rate"],
                              physics_success_ci95=p["success_ci95"])
    return out


def run_cell(models: Sequence[str | Path], cycles: int, out_dir: str | Path, threads: int = 2, seed: int = 0,
             engine: Engine = Engine.ONNXRUNTIME, progress=print, verdict: VerdictRule = VerdictRule.GEOMETRIC,
             physics_config=None, rounds: int | None = None, round_config=None, margin_pp: float = 1.0,
             measured: list[Measured] | None = None, hand: HandShape | None = None) -> dict:
    """The true-label row, then each model's, over the same CYCLES scenes (with ROUNDS: that many
    clutter-removal rounds, sim/clutter.py, laid out alike for every row); each int8 row against the
    fp32 row on those scenes, with its paired interval read against +-MARGIN_PP percentage points
    (bench/compare.py, "equivalence"); writes cell.md/.csv/.json and success-latency.png in OUT_DIR.
    MEASURED, when given, gets each row's cycles as they ran (to compare over several runs). HAND:
    measure_row's."""
    if not (math.isfinite(margin_pp) and 0 < margin_pp < 100):
        raise ParameterError("{margin_pp}: must be a number of percentage points in (0, 100)", margin_pp=margin_pp)
    if rounds is not None and rounds < 1:
        raise ParameterError("{rounds}: must be at least 1", rounds=rounds)
    for m in models:  # every model's contract before the first cycle
        check_model(m)
    camera = SynthCamera(640, 480, seed=seed, mount_height_m=MOUNT_M)
    what = f"{cycles} cycles" if rounds is None else f"{rounds} rounds"
    progress(f"cell: true labels, {what} ...")
    row, results, described = measure_row("true labels", "-", TruthPipeline(list(CLASSES), camera.calibration()),
                                          cycles, seed, None, verdict, physics_config, rounds, round_config, hand)
    measured = [] if measured is None else measured
    rows = [row]
    measured.append(Measured(row.mode, "-", results, described))
    for m in models:
        seg = Segmenter(m, threads=threads, engine=engine)
        progress(f"cell: {Path(m).name}, {what} ...")
        row, results, described = measure_row(mode_label(seg.info), str(m), Pipeline(seg, camera.calibration()),
                                              cycles, seed, round(Path(m).stat().st_size / 1e6, 3), verdict,
                                              physics_config, rounds, round_config, hand)
        rows.append(row)
        measured.append(Measured(row.mode, seg.info.precision, results, described))
    modes = [r.mode for r in rows]
    for r, kept in zip(rows, measured[-len(rows):]):  # two models of one mode (the demo's hybrid, the reference): name the files
        if modes.count(r.mode) > 1:
            r.mode = kept.mode = f"{r.mode} ({Path(r.model).stem})"
    title = f"{cycles} executions per model" if rounds is None else f"{rounds} clutter-removal rounds per model"
    context = {"title": f"Table 5.6 in the synthetic cell: {title}",
               "machine": machine_line().removeprefix("Machine: "), "onnxruntime": ort.__version__, "opencv": cv2.__version__,
               "threads": threads, "engine": engine, "scenes": f"SynthCamera seed {seed}, 640x480, {MOUNT_M} m above the table",
               "criterion": "docs/contracts.md#grasp-success", "verdict": str(verdict)}
    if rounds is not None:
        context["rounds"] = "docs/contracts.md#clutter-removal-rounds"
    compared = compare(measured[-len(rows):], margin_pp / 100)
    return {"rows": [asdict(r) for r in rows], "equivalence": compared,
            "reports": write_cell_reports(rows, out_dir, context, compared)}


PHYSICS_HEADER = ["Physics success (%)", "of standing scenes (%)", "Physics failures", "Check p50 (ms)"]


def _pct(v: float | None) -> str:
    return "-" if v is None else f"{100 * v:.0f}"


def _ci(ci: list[float] | None) -> str:
    """A 95% interval as the tables show it beside its rate: " [lo, hi]" in percent."""
    return "" if ci is None else f" [{100 * ci[0]:.1f}, {100 * ci[1]:.1f}]"


def _kinds(failures: dict[str, int]) -> str:
    return ", ".join(f"{k} {v}" for k, v in failures.items()) or "-"


def header(rows: list[CellRow]) -> list[str]:
    """The table's columns: HEADER, and the physics check's where it ran."""
    return HEADER + (PHYSICS_HEADER if any(r.physics for r in rows) else [])


def table(rows: list[CellRow]) -> list[list[str]]:
    physics = any(r.physics for r in rows)
    out = []
    for r in rows:
        line = [r.mode, f"{r.mean_ms:.1f} [{r.std_ms:.1f}]", f"{r.p50_ms:.1f}", f"{r.p95_ms:.1f}",
                "-" if r.size_mb is None else f"{r.size_mb:.2f}",
                f"{_pct(r.success_rate)} ({r.success}/{r.cycles}){_ci(r.success_ci95)}",
                _pct(r.success_rate_reachable) + _ci(r.success_reachable_ci95), _kinds(r.failures)]
        if physics:
            p = r.physics or {}
            line += [f"{_pct(p.get('success_rate'))} ({p.get('success', 0)}/{p.get('executions', 0)})"
                     f"{_ci(p.get('success_ci95'))}",
                     _pct(p.get("success_rate_standing")) + _ci(p.get("success_standing_ci95")),
                     _kinds(p.get("failures", {})),
                     "-" if p.get("ms_p50") is None else f"{p['ms_p50']:.0f}"]
        out.append(line)
    return out


def sections(rows: list[CellRow], compared: list[dict] | tuple = ()) -> list[str]:
    """Markdown below the table: success per light condition (thesis Table 5.3), with the physics check
    the cycles where the two verdicts disagree, by class, with rounds the clutter removal summed and per
    light condition, and each int8 row against fp32 (COMPARED: bench/compare.py's entries)."""
    seen = {light for r in rows for light in r.by_lighting}
    lights = [light for light in LIGHTINGS if light in seen] + sorted(seen - set(LIGHTINGS))
    physics = any(r.physics for r in rows)
    out = ["", "## By light condition (thesis Table 5.3)", "",
           "Grasp success (%) and executions per light condition of the scenes" +
           (" (geometric / physics)" if physics else "") + "; objects of the scenes no grasp record found:", ""]

    def cell(d: dict | None) -> str:
        if not d:
            return "-"
        text = f"{_pct(d['success_rate'])} ({d['success']}/{d['executions']}){_ci(d.get('success_ci95'))}"
        if "physics_success_rate" in d:
            text += f" / {_pct(d['physics_success_rate'])}{_ci(d.get('physics_success_ci95'))}"
        return text + f"; {d['undetected']} not found"

    out.append(markdown(["Mode", *lights], [[r.mode, *(cell(r.by_lighting.get(light)) for light in lights)]
                                            for r in rows]))
    if physics:
        classes = list(dict.fromkeys(c for r in rows for c in r.disagreements))
        out += ["", "## Where the geometric rule and the physics check disagree", "",
                "Cycles per class of the chosen target that only one of the two passed "
                "(geometric only: the rule's tolerance is too generous there; physics only: too strict):", ""]
        out.append(markdown(["Mode", *classes], [[r.mode, *(
            f"{r.disagreements[c]['geometric only']} / {r.disagreements[c]['physics only']}" if c in r.disagreements
            else "0 / 0" for c in classes)] for r in rows]) if classes else "None.")
    with_rounds = [(r.mode, r.rounds) for r in rows if r.rounds]
    if with_rounds:
        light_seen = {light for _, rounds in with_rounds for light in rounds["by_lighting"]}
        out += rounds_section([mode for mode, _ in with_rounds], [rounds for _, rounds in with_rounds],
                              [light for light in LIGHTINGS if light in light_seen])
    return out + compare_section(list(compared))


def write_cell_reports(rows: list[CellRow], out_dir: str | Path, context: dict,
                       compared: list[dict] | tuple = ()) -> dict[str, str]:
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {"md": out / "cell.md", "csv": out / "cell.csv", "json": out / "cell.json", "png": out / "success-latency.png"}
    md = [f"# {context['title']}", ""] + [f"- {k}: {v}" for k, v in context.items() if k != "title"]
    paths["md"].write_text("\n".join(md + ["", markdown(header(rows), table(rows)), *sections(rows, compared)]) + "\n")
    with open(paths["csv"], "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(header(rows))
        writer.writerows(table(rows))
    paths["json"].write_text(json.dumps({"context": context, "rows": [asdict(r) for r in rows],
                                         "equivalence": list(compared)}, indent=1))
    _plot(rows, paths["png"])
    return {k: str(v) for k, v in paths.items()}


FONT, SCALE = cv2.FONT_HERSHEY_SIMPLEX, 0.45
TRUTH_GREY = (128, 128, 128)  # the true-label row: the grasp step's ceiling, timed without a model
COLOURS = [(200, 80, 30), (30, 140, 30), (30, 30, 200), (160, 30, 160), (0, 140, 200), (40, 90, 160)]


def _overlap(a: tuple[int, int, int, int], b: tuple[int, int, int, int]) -> int:
    return max(0, min(a[2], b[2]) - max(a[0], b[0])) * max(0, min(a[3], b[3]) - max(a[1], b[1]))


def _place_labels(points: list[tuple[int, int]], sizes: list[tuple[int, int]],
                  frame: tuple[int, int, int, int]) -> list[tuple[int, int, int, int]]:
    """A box (x0, y0, x1, y1) per label of size (w, h) beside its point: inside FRAME, clear of the labels
    placed before it and of every point, shifted up or down by whole lines when the spot beside it is taken
    (the least crowded spot nearest the point when none is clear)."""
    left, right, top, bottom = frame
    marks = [(x - 7, y - 7, x + 8, y + 8) for x, y in points]
    placed: list[tuple[int, int, int, int]] = []
    for (x, y), (tw, th) in zip(points, sizes):
        best, best_cost = None, None
        for k in range(2 * len(points) + 1):
            shift = (k + 1) // 2 * (-1 if k % 2 else 1) * (th + 4)  # 0, -1, +1, -2, +2 ... lines
            y0 = y - th // 2 + shift
            if y0 < top + 2 or y0 + th > bottom - 2:
                continue
            for x0 in (x + 10, x - 10 - tw):
                x0 = min(max(x0, left + 2), right - 2 - tw)
                box = (x0, y0, x0 + tw, y0 + th)
                cost = sum(_overlap(box, b) for b in placed + marks)
                if best_cost is None or cost < best_cost:
                    best, best_cost = box, cost
            if best_cost == 0:
                break
        placed.append(best or (x + 10, y - th // 2, x + 10 + tw, y - th // 2 + th))  # a frame too short for a line
    return placed


def _plot(rows: list[CellRow], path: Path, w: int = 800,
          h: int = 520) -> list[tuple[tuple[int, int], tuple[int, int, int, int]]]:
    """Grasp success (%) against pipeline p50 (ms), one point per row labelled with its full mode, the
    true-label row in grey. Returns each row's point and label box (x0, y0, x1, y1) in pixels."""
    labels = [cv2.getTextSize(r.mode, FONT, SCALE, 1) for r in rows]
    sizes = [(tw, th + base) for (tw, th), base in labels]
    w = max([w] + [tw + 80 + 30 + 40 for tw, _ in sizes])  # room for the longest label beside any point
    img = np.full((h, w, 3), 255, np.uint8)
    frame = (80, w - 30, 40, h - 60)
    span = max([r.p50_ms for r in rows] + [0.1]) * 1.1  # round ticks from 0 to just past the slowest row
    unit = 10 ** math.floor(math.log10(span / 5))
    step = next(m * unit for m in (1, 2, 5, 10) if m * unit >= span / 5)
    xticks = [k * step for k in range(math.ceil(span / step) + 1)]
    px = draw_axes(img, frame, (0.0, xticks[-1]), (-5.0, 105.0), xticks, list(range(0, 101, 20)), ("{:g}", "{:.0f}"),
                   ("pipeline p50 (ms)", "grasp success (%)"))
    points = [px(r.p50_ms, 100 * r.success_rate) for r in rows]
    boxes = _place_labels(points, sizes, frame)
    colours = cycle(COLOURS)
    colour = [TRUTH_GREY if r.model == "-" else next(colours) for r in rows]  # model "-": the true-label row
    for (x, y), box, c in zip(points, boxes, colour):
        if not box[1] <= y <= box[3]:  # a label moved off its point's line: a leader to its nearest edge
            cv2.line(img, (x, y), (min(max(x, box[0]), box[2]), min(max(y, box[1]), box[3])), c, 1, cv2.LINE_AA)
    for (x, y), c in zip(points, colour):
        cv2.circle(img, (x, y), 6, c, -1, cv2.LINE_AA)
    for r, box, c, ((_, th), _) in zip(rows, boxes, colour, labels):  # on white, above the leaders that cross
        cv2.rectangle(img, (box[0] - 1, box[1] - 1), (box[2] + 1, box[3] + 1), (255, 255, 255), -1)
        cv2.putText(img, r.mode, (box[0], box[1] + th), FONT, SCALE, c, 1, cv2.LINE_AA)
    if not cv2.imwrite(str(path), img):
        raise OSError(f"could not write {path}")
    return list(zip(points, boxes))
