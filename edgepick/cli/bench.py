"""`edgepick bench` on the command line (click only; the measuring needs no torch)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import click

from edgepick.cli.options import choice, round_config
from edgepick.data.config import Split
from edgepick.errors import ConfigError
from edgepick.files import check_output, output_dir
from edgepick.robot.verdict import VerdictRule
from edgepick.runtime.engine import Engine


@click.command()
@click.argument("models", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option("--data", default=None, type=click.Path(file_okay=False),
              help="Data set (native layout) for accuracy and timing (not needed with --cell).")
@click.option("--split", default=Split.TEST.value, show_default=True, type=choice(Split))
@click.option("--threads", default=2, show_default=True, help="onnxruntime intra-op threads for every row.")
@click.option("--runs", default=50, show_default=True, help="Timed inferences per model (after warm-up).")
@click.option("--out", "out_dir", default="bench-out", show_default=True, type=click.Path(file_okay=False),
              help="Folder for table.md, table.csv, table.json and miou-latency.png (cell.* and success-latency.png "
                   "with --cell): new, empty, or one bench made before (its files of the same names are replaced).")
@click.option("--gpu-checkpoint", default=None, type=click.Path(), help="Float RUN or checkpoint for the fp32 GPU row (needs CUDA).")
@click.option("--no-pipeline", is_flag=True, help="Skip the Table 5.6 pipeline timing.")
@click.option("--cell", type=int, is_flag=False, flag_value=50, default=None, metavar="N",
              help="Instead: N executions of the whole pick loop per model in the synthetic cell (SimRobot, the same "
                   "seeded scenes for every model; --cell alone: 50, the thesis's count): pipeline time, size and grasp "
                   "success (docs/contracts.md#grasp-success), with a first row on the scenes' true labels.")
@click.option("--seed", default=0, show_default=True, help="--cell: the scenes' seed.")
@click.option("--rounds", default=None, type=int,
              help="--cell in clutter-removal rounds (the [sim] extra): N rounds per model, each laying out 4-10 parts "
                   "once (alike for every model) and picking until the table is empty, two failures in a row or "
                   "--max-cycles; grasp success, clearance, picks per part, failures and time per pick, per light "
                   "condition, with 95% intervals (docs/contracts.md#clutter-removal-rounds). --cell's N is not used.")
@click.option("--max-cycles", default=None, type=int, help="--rounds: cycles per round at most [default: none].")
@click.option("--margin", "margin_pp", default=1.0, show_default=True,
              help="--cell: each int8 model against the fp32 one on the same scenes: equivalent when the paired 95% "
                   "interval of their success rates' difference lies within +-this many percentage points.")
@click.option("--verdict", default=VerdictRule.GEOMETRIC.value, show_default=True, type=choice(VerdictRule),
              help="--cell: the verdict on each cycle: the geometric rule (docs/contracts.md#grasp-success), or "
                   "also the physics check (the grasp carried out in MuJoCo: the [sim] extra; physics and both "
                   "report both, and where they disagree by class).")
@click.option("--engine", default=Engine.ONNXRUNTIME.value, show_default=True, type=choice(Engine),
              help="Inference engine for every row (openvino: the [peers] extra; auto: the faster one here, measured "
                   "once per model and cached).")
def bench(models: tuple[str, ...], data: str | None, split: Split, threads: int, runs: int, out_dir: str,
          gpu_checkpoint: str | None, no_pipeline: bool, cell: int | None, seed: int, rounds: int | None,
          max_cycles: int | None, margin_pp: float, verdict: VerdictRule, engine: Engine) -> None:
    """Thesis Tables 5.5 and 5.6 for MODEL... (ONNX): pixel accuracy, mIoU, inference p50/p95 at
    fixed threads, training time (from the model's metadata), size, and the whole pipeline per
    frame (folder frame -> labels -> grasp records). Same images for every row, one process.
    With --cell N: Table 5.6 with its grasp success column, N pick cycles per model in the
    synthetic cell (cell.md, cell.csv, cell.json, success-latency.png)."""
    from edgepick.bench.measure import BenchConfig, Row
    from edgepick.bench.report import HEADER_55, markdown, table55_rows
    from edgepick.bench.run import run_bench

    check_output(out_dir, "--out", kind="dir", inputs=(*models, data), reuse="bench")
    cfg = BenchConfig(threads=threads, runs=runs, split=split, engine=engine)
    if seed < 0:
        raise ConfigError(f"--seed {seed}: must be 0 or positive")
    for m in models:
        if Path(m).suffix.lower() != ".onnx":
            raise ConfigError(f"{m} is not an .onnx file (bench runs ONNX models through the runtime)")
    round_cfg = _check_rounds(rounds, max_cycles, margin_pp)
    if rounds is not None and cell is None:
        cell = 50  # rounds run in the cell: --rounds alone means --cell --rounds
    if cell is not None:
        from edgepick.bench.cell import CellRow, header, run_cell, sections, table

        if cell < 1:
            raise ConfigError(f"--cell {cell}: the number of executions must be at least 1")
        if gpu_checkpoint is not None:
            raise ConfigError("--gpu-checkpoint is for the table of --data; --cell times the ONNX models' pick loop")
        if verdict != VerdictRule.GEOMETRIC or round_cfg is not None:
            from edgepick.sim.physics import require_mujoco

            require_mujoco()  # the [sim] extra, before the first cycle
        with output_dir(out_dir, "bench"):
            result = run_cell(list(models), cell, out_dir, threads=cfg.threads, seed=seed, engine=cfg.engine,
                              progress=lambda line: click.echo(line, err=True), verdict=verdict, rounds=rounds,
                              round_config=round_cfg, margin_pp=margin_pp)
        cell_rows = [CellRow(**r) for r in result["rows"]]
        click.echo("\n".join([markdown(header(cell_rows), table(cell_rows)), *sections(cell_rows, result["equivalence"])]),
                   err=True)
        click.echo(json.dumps(result, indent=1))
        return
    if data is None:
        raise ConfigError("--data is needed (the data set to measure accuracy and timing on), or --cell N")

    with output_dir(out_dir, "bench"):
        result = run_bench(list(models), data, out_dir, cfg,
                           gpu_checkpoint=gpu_checkpoint, with_pipeline=not no_pipeline,
                           progress=lambda line: click.echo(line, err=True))
    rows = [Row(**r) for r in result["rows"]]
    click.echo(markdown(HEADER_55, table55_rows(rows)), err=True)
    click.echo(json.dumps(result, indent=1))


def _check_rounds(rounds: int | None, max_cycles: int | None, margin_pp: float):
    """--rounds, --max-cycles and --margin checked before anything starts: the RoundConfig of --rounds
    (None without it)."""
    if not (math.isfinite(margin_pp) and 0 < margin_pp < 100):
        raise ConfigError(f"--margin {margin_pp}: must be a number of percentage points in (0, 100)")
    return round_config(rounds, max_cycles)
