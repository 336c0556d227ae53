"""Grasp success in the synthetic cell under the geometric rule and under physics, per class of
disagreement and per light condition (thesis Tables 5.6 and 5.3): `bench --cell N --verdict both`
for the shipped reference model, with a first row on the scenes' true labels.

    python benchmarks/cell_verdicts.py [--cycles 500] [--model m.onnx ...] [--stroke 0.110] [--seed 0]
                                       [--out FILE.md | --save]

--stroke sets the simulated parallel jaw's stroke (an RG2: 110 mm; an RG6: 160 mm). The report is
bench's cell.md under this script's command and machine line.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from _common import add_output, emit  # noqa: E402

from edgepick.bench.cell import run_cell  # noqa: E402
from edgepick.reference import reference_model  # noqa: E402
from edgepick.robot.verdict import VerdictRule  # noqa: E402
from edgepick.sim.physics import PhysicsConfig  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cycles", type=int, default=500)
    ap.add_argument("--model", action="append", default=None, help="ONNX model(s) [default: the reference model]")
    ap.add_argument("--stroke", type=float, default=PhysicsConfig().jaw_stroke_m, help="the jaw's stroke, metres")
    ap.add_argument("--seed", type=int, default=0)
    add_output(ap)
    args = ap.parse_args()
    cfg = PhysicsConfig(jaw_stroke_m=args.stroke)
    with tempfile.TemporaryDirectory() as tmp:
        run_cell(args.model or [str(reference_model())], args.cycles, tmp, seed=args.seed, verdict=VerdictRule.BOTH,
                 physics_config=cfg, progress=lambda line: print(line, file=sys.stderr))
        body = (Path(tmp) / "cell.md").read_text().split("\n", 1)[1]
    report = (f"# Grasp success by the geometric rule and by physics: {args.cycles} cycles, jaw stroke "
              f"{1000 * args.stroke:.0f} mm\n\nCommand: `python benchmarks/cell_verdicts.py {' '.join(sys.argv[1:])}`\n"
              + body)
    emit(report, args, suffix=f"stroke-{1000 * args.stroke:.0f}mm")


if __name__ == "__main__":
    main()
