"""Clutter removal in the synthetic physics cell, as the grasping benchmarks measure it (VGN, GIGA):
`bench --cell --rounds N --verdict physics` for the reference model's files, with a first row on the
scenes' true labels; grasp success and clearance with their 95% intervals, per light condition, and
each int8 file against the fp32 one on the same tables (docs/contracts.md#clutter-removal-rounds).

    python benchmarks/clutter_rounds.py [--rounds 100] [--run reference-run/models] [--models A.onnx ...]
                                        [--seed 0] [--verdict physics] [--margin 1] [--finger-room MM]
                                        [--out FILE.md | --save]

The models: the shipped int8 file (edgepick/reference/), and beside it the fp32 and hybrid files of
`bash benchmarks/reference_model.sh` where --run holds them (edgepick ships only the int8 file);
--models replaces the list. The report is bench's cell.md under this script's command, machine and
library versions, then the targets the rounds are held to, and the wall time per round.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
import onnxruntime as ort

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from _common import add_output, emit, machine_line  # noqa: E402

from edgepick.bench.cell import run_cell  # noqa: E402
from edgepick.bench.report import markdown  # noqa: E402
from edgepick.reference import reference_model  # noqa: E402
from edgepick.robot.clearance import HandShape  # noqa: E402
from edgepick.robot.verdict import VerdictRule  # noqa: E402

SUCCESS, CLEARANCE, PER_LIGHT, HALF_WIDTH = 0.95, 0.95, 0.90, 0.03  # the targets (this script's docstring)


def models_of(args: argparse.Namespace) -> list[str]:
    """--models, or the fp32 file of --run, the shipped int8 file and the hybrid file of --run (those there)."""
    if args.models:
        missing = [m for m in args.models if not Path(m).is_file()]
        if missing:
            raise SystemExit(f"no model at {', '.join(missing)}")
        return args.models
    run = Path(args.run)
    shipped = reference_model()
    if shipped is None:
        raise SystemExit("this install has no reference model (edgepick/reference/): give --models")
    found = [str(run / "fp32.onnx")] if (run / "fp32.onnx").is_file() else []
    return found + [str(shipped)] + ([str(run / "hybrid.onnx")] if (run / "hybrid.onnx").is_file() else [])


def shown(path: str) -> str:
    """A model's path as the report names it: from the repository's root when it lies inside it."""
    repo = Path(__file__).resolve().parents[1]
    full = Path(path).resolve()
    return str(full.relative_to(repo)) if full.is_relative_to(repo) else path


def hand_line(hand: HandShape) -> str:
    """How the planner opened the jaw (robot/clearance.py jaw_opening_m), in the report's words."""
    return (f"a jaw opened to the part's width plus {1000 * hand.finger_room_m:.0f} mm a finger, at most its "
            f"{1000 * hand.jaw_opening_m:.0f} mm stroke; turned to close on the part's ends, opened all the way, "
            "where its sides are crowded")


def targets(rows: list[dict], equivalence: list[dict], margin: float) -> list[list[str]]:
    """Each target the rounds are held to, what was measured, and whether it holds."""
    out = []
    found = reference_model()
    shipped = next((r for r in rows if found is not None and Path(r["model"]).resolve() == found.resolve()), None)
    if shipped is not None:
        s = shipped["rounds"]

        def held(value, ci, bound) -> list[str]:
            text = "-" if value is None else f"{100 * value:.1f}% [{100 * ci[0]:.1f}, {100 * ci[1]:.1f}]"
            return [text, "-" if value is None else ("yes" if value >= bound else "no")]

        out.append([f"reference int8: grasp success >= {100 * SUCCESS:.0f}%",
                    *held(s["success_rate"], s["success_ci95"], SUCCESS)])
        out.append([f"reference int8: clearance >= {100 * CLEARANCE:.0f}%",
                    *held(s["clearance"], s["clearance_ci95"], CLEARANCE)])
        for light, d in s["by_lighting"].items():
            out.append([f"reference int8, {light}: grasp success >= {100 * PER_LIGHT:.0f}%",
                        *held(d["success_rate"], d["success_ci95"], PER_LIGHT)])
            out.append([f"reference int8, {light}: clearance >= {100 * PER_LIGHT:.0f}%",
                        *held(d["clearance"], d["clearance_ci95"], PER_LIGHT)])
    for r in rows:
        ci = r["rounds"]["clearance_ci95"]
        half = None if ci is None else (ci[1] - ci[0]) / 2
        out.append([f"{r['mode']}: clearance interval narrower than +-{100 * HALF_WIDTH:.0f} pp",
                    "-" if half is None else f"+-{100 * half:.1f} pp", "-" if half is None else
                    ("yes" if half < HALF_WIDTH else "no")])
    for e in equivalence:
        if e["rate"] == "grasp success" and e["verdict"] == "physics":
            ci = e["ci95"]
            out.append([f"{e['mode']} minus {e['against']}: grasp success within +-{margin:g} pp",
                        "-" if ci is None else f"{100 * e['difference']:+.2f} pp [{100 * ci[0]:+.2f}, {100 * ci[1]:+.2f}]",
                        {"within": "yes", "outside": "no", "undecided": "undecided", None: "-"}[e["equivalence"]]])
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=100)
    ap.add_argument("--run", default="reference-run/models", help="where the fp32 and hybrid files are")
    ap.add_argument("--models", nargs="*", default=None, help="ONNX models [default: see the docstring]")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--verdict", default=VerdictRule.PHYSICS.value, choices=[v.value for v in VerdictRule])
    ap.add_argument("--max-cycles", type=int, default=None)
    ap.add_argument("--margin", type=float, default=1.0, help="int8 against fp32: the equivalence margin, percentage points")
    ap.add_argument("--finger-room", type=float, default=None,
                    help="mm beside the part for each finger when the jaw opens [default: HandShape's]; "
                         "a large value opens the whole stroke")
    add_output(ap)
    args = ap.parse_args()
    models = models_of(args)
    from edgepick.sim.clutter import RoundConfig
    from edgepick.sim.physics import require_mujoco

    mujoco = require_mujoco()
    marks: list[tuple[str, float]] = []

    def progress(line: str) -> None:
        marks.append((line, time.perf_counter()))
        print(line, file=sys.stderr)

    with tempfile.TemporaryDirectory() as tmp:
        hand = None if args.finger_room is None else HandShape(finger_room_m=args.finger_room / 1000)
        cell = run_cell(models, 1, tmp, seed=args.seed, progress=progress, verdict=VerdictRule(args.verdict),
                        rounds=args.rounds, round_config=RoundConfig(max_cycles=args.max_cycles), margin_pp=args.margin,
                        hand=hand)
        end = time.perf_counter()
        body = (Path(tmp) / "cell.md").read_text().split("\n", 1)[1]
    walls = [later - at for (_, at), (_, later) in zip(marks, [*marks[1:], ("", end)])]
    timing = markdown(["Row", "Rounds", "Picks", "Wall time (s)", "per round (s)", "per pick (s)"],
                      [[r["mode"], str(args.rounds), str(r["cycles"]), f"{w:.0f}", f"{w / args.rounds:.1f}",
                        f"{w / max(1, r['cycles']):.2f}"] for r, w in zip(cell["rows"], walls)])
    held = markdown(["Target", "Measured [95% CI]", "Holds"], targets(cell["rows"], cell["equivalence"], args.margin))
    report = (f"# Clutter removal in the physics cell: {args.rounds} rounds per model\n\n"
              f"Command: `python benchmarks/clutter_rounds.py {' '.join(sys.argv[1:])}`  \n"
              f"{machine_line()}; onnxruntime {ort.__version__}, opencv {cv2.__version__}, numpy {np.__version__}, "
              f"mujoco {mujoco.__version__}\n\nModels: {', '.join(f'`{shown(m)}`' for m in models)}  \n"
              f"Hand: {hand_line(hand or HandShape())}\n"
              f"{body}\n## Targets\n\n{held}\n\n## Time\n\nWall time of each row on this machine (rendering, "
              f"inference, the physics check and the settling):\n\n{timing}\n")
    emit(report, args)


if __name__ == "__main__":
    main()
