"""Thesis Table 5.6 with its grasp success column, in the synthetic cell: `edgepick bench --cell`
on the given models (by default fp32, static, QaT and hybrid-QaT 10% of those `make demo` leaves in
demo-out/models), with the
scenes' true labels as the first row (the grasp step's own ceiling).

    python benchmarks/grasp_success.py [--models A.onnx B.onnx ...] [--cycles 50] [--seed 0] [--margin 1] [--save]

Every rate carries its 95% Wilson interval, and each int8 model is compared with the fp32 one on
the same scenes (all the scene sets together): the paired interval of the difference, and whether
it lies within +-margin percentage points (docs/contracts.md#clutter-removal-rounds).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from _common import add_output, emit  # noqa: E402

from edgepick.bench.cell import run_cell  # noqa: E402
from edgepick.bench.compare import Measured, compare, compare_section  # noqa: E402
from edgepick.bench.report import markdown  # noqa: E402
from edgepick.intervals import wilson  # noqa: E402

NOTE = ("The models are `make demo`'s (demo-out/summary.json says how they were trained and their test mIoU), "
        "far too weak for the cell; the true-label row is what the grasp step does with a perfect segmentation.\n")
DEMO = [f"demo-out/models/{name}.onnx" for name in ("fp32", "static", "qat", "hybrid0.10")]


def parse_args(doc: str, models: list[str], spread: str) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=doc.splitlines()[0])
    ap.add_argument("--models", nargs="*", default=models)
    ap.add_argument("--cycles", type=int, default=50)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--spread-seeds", default=spread, help="other scene sets, comma-separated, every row run on each (the spread)")
    ap.add_argument("--margin", type=float, default=1.0, help="int8 against fp32: the equivalence margin, percentage points")
    add_output(ap)
    args = ap.parse_args()
    missing = [m for m in args.models if not Path(m).is_file()]
    if missing:
        raise SystemExit(f"no model at {', '.join(missing)} (see this script's docstring for how to make them)")
    return args


def cell_report(args: argparse.Namespace, script: str, note: str) -> None:
    """`bench --cell` on ARGS.models, then every row again on the spread seeds' scenes (the spread
    between sets of 50 scenes, and the success over all of them); printed and saved."""
    seeds = [args.seed] + [int(v) for v in args.spread_seeds.split(",") if v.strip()]
    runs, measured = {}, []
    for seed in seeds:
        with tempfile.TemporaryDirectory() as tmp:
            cell = run_cell(args.models, args.cycles, tmp, seed=seed, progress=lambda line: print(line, file=sys.stderr),
                            margin_pp=args.margin, measured=measured)
            runs[seed] = cell["rows"]
            if seed == args.seed:
                table_md = (Path(tmp) / "cell.md").read_text()
    command = (f"{script} --models {' '.join(args.models)} --cycles {args.cycles} "
               f"--seed {args.seed} --spread-seeds {args.spread_seeds} --margin {args.margin:g}")
    body = table_md.split("\n", 1)[1]
    if len(seeds) > 1:
        body += ("\nGrasp success on each set of scenes (`--seed`, then `--spread-seeds`), and over all of them with "
                 "its 95% Wilson interval:\n\n" + markdown(*spread_table(runs)) + "\n")
        every = [Measured(m.mode, m.precision, [r for other in measured if other.mode == m.mode for r in other.results])
                 for m in measured[:len(runs[args.seed])]]  # each row's cycles over every set, in the same order
        section = compare_section(compare(every, args.margin / 100))
        if section:
            body += "\n".join(section).replace("## int8 against fp32 on the same scenes",
                                               f"## int8 against fp32 on the same {len(seeds) * args.cycles} scenes") + "\n"
    emit(f"# Grasp success in the synthetic cell (thesis Table 5.6), {args.cycles} executions per model\n\n"
         f"Command: `{command}` (the same as `edgepick bench MODELS --cell {args.cycles} --seed {args.seed}`)\n"
         f"{body}\n{note}", args)


def spread_table(runs: dict[int, list[dict]]) -> tuple[list[str], list[list[str]]]:
    """Mode | successes per seed | all seeds: one row per mode of the first seed's table."""
    seeds = list(runs)
    header = ["Mode"] + [f"seed {s}" for s in seeds] + ["all seeds"]
    rows = []
    for i, first in enumerate(runs[seeds[0]]):
        cells = [runs[s][i] for s in seeds]
        won, total = sum(c["success"] for c in cells), sum(c["cycles"] for c in cells)
        lo, hi = wilson(won, total)
        rows.append([first["mode"]] + [f"{c['success']}/{c['cycles']}" for c in cells]
                    + [f"{100 * won / total:.1f}% ({won}/{total}) [{100 * lo:.1f}, {100 * hi:.1f}]"])
    return header, rows


def main() -> None:
    args = parse_args(__doc__, DEMO, "1,2")
    cell_report(args, "python benchmarks/grasp_success.py", NOTE if args.models == DEMO else "")


if __name__ == "__main__":
    main()
