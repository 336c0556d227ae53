"""Grasp success per light condition (thesis Table 5.3) of int8 models trained with and without
`train --augment lights`, on the same cell cycles: `bench --cell N --verdict both` for every file,
then each training setting's mean and spread over its seeds.

    python benchmarks/lighting_augment.py OUT/basic-s0.onnx OUT/basic-s1.onnx OUT/lights-s0.onnx ...
                                          [--runs WORK] [--cycles 500] [--seed 0] [--reference]
                                          [--out FILE.md | --save]

A file named SETTING-sN.onnx is seed N of SETTING (benchmarks/lighting_gpu.sh writes them so);
--runs WORK adds each run's best validation mIoU from WORK/SETTING-sN/metrics.json; --reference
adds the shipped reference model as a row (trained longer, with --augment basic).
"""

from __future__ import annotations

import argparse
import json
import re
import statistics
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from _common import add_output, emit  # noqa: E402

from edgepick.bench.cell import run_cell  # noqa: E402
from edgepick.bench.report import markdown  # noqa: E402
from edgepick.data.render import LIGHTINGS  # noqa: E402
from edgepick.reference import reference_model  # noqa: E402
from edgepick.robot.verdict import VerdictRule  # noqa: E402
from edgepick.train.run import Run  # noqa: E402

SEEDED = re.compile(r"^(?P<setting>.+)-s(?P<seed>\d+)$")


def setting_of(model: str) -> str:
    """basic-s1.onnx -> basic; a file not named SETTING-sN is a setting of its own."""
    stem = Path(model).stem
    match = SEEDED.match(stem)
    return match["setting"] if match else stem


def spread(values: list[float]) -> str:
    """'91.3 (89.7-92.9)': the mean over seeds and its range, in percent."""
    mean = 100 * statistics.fmean(values)
    if len(values) == 1:
        return f"{mean:.1f}"
    return f"{mean:.1f} ({100 * min(values):.1f}-{100 * max(values):.1f})"


def setting_table(rows: list[dict], models: list[str], key: str) -> list[list[str]]:
    """Per training setting: the success rate (KEY: success_rate or physics_success_rate) per light
    condition and overall, as mean (range) over the setting's seeds."""
    by_setting: dict[str, list[dict]] = {}
    for model, row in zip(models, rows):
        by_setting.setdefault(setting_of(model), []).append(row)
    table = []
    for setting, seeds in by_setting.items():
        cells = [spread([r["by_lighting"][light][key] for r in seeds]) for light in LIGHTINGS]
        overall = [r["success_rate"] if key == "success_rate" else r["physics"]["success_rate"] for r in seeds]
        table.append([setting, str(len(seeds)), *cells, spread(overall)])
    return table


def best_miou(runs: Path, model: str) -> str:
    """The best validation mIoU (%) of MODEL's training run in RUNS, or '-' without one."""
    metrics = Run(runs / Path(model).stem).metrics
    if not metrics.is_file():
        return "-"
    return f"{100 * json.loads(metrics.read_text())['best_miou']:.2f}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("models", nargs="+", help="int8 ONNX files, named SETTING-sN.onnx")
    ap.add_argument("--runs", type=Path, default=None, help="the folder holding each file's training run")
    ap.add_argument("--cycles", type=int, default=500)
    ap.add_argument("--seed", type=int, default=0, help="the cell's scene seed")
    ap.add_argument("--reference", action="store_true", help="add the shipped reference model")
    add_output(ap)
    args = ap.parse_args()
    models = [*args.models, *([str(reference_model())] if args.reference else [])]
    with tempfile.TemporaryDirectory() as tmp:
        result = run_cell(models, args.cycles, tmp, seed=args.seed, verdict=VerdictRule.BOTH,
                          progress=lambda line: print(line, file=sys.stderr))
        cell = (Path(tmp) / "cell.md").read_text().split("\n", 1)[1]
    rows = result["rows"][1:]  # the first row is the scenes' true labels
    head = ["Setting", "seeds", *LIGHTINGS, "all"]
    files = [[Path(m).name, setting_of(m), best_miou(args.runs, m) if args.runs else "-"] for m in models]
    report = (f"# Grasp success per light condition with and without `train --augment lights`: {args.cycles} cycles\n\n"
              f"Command: `python benchmarks/lighting_augment.py {' '.join(sys.argv[1:])}`\n\n"
              "## Per training setting (mean over seeds, range in brackets; %)\n\n"
              "Geometric rule (docs/contracts.md#grasp-success):\n\n"
              + markdown(head, setting_table(rows, models, "success_rate"))
              + "\n\nPhysics check (docs/contracts.md#physics-verdict):\n\n"
              + markdown(head, setting_table(rows, models, "physics_success_rate"))
              + "\n\n## Files\n\n" + markdown(["File", "setting", "best val mIoU (%)"], files)
              + "\n\n## The cell's report\n" + cell)
    emit(report, args)


if __name__ == "__main__":
    main()
