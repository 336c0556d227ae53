"""The command line of benchmarks/conformance.py: which models and engines, where the files go, and
the exit status (1 when a pinned reference regressed)."""

from __future__ import annotations

import argparse
import shlex
import sys
import time
from collections.abc import Sequence
from datetime import date
from pathlib import Path

from _common import RESULTS, machine_line

from edgepick.machine import machine_slug, results_file

from . import engines as engine_table
from .fetch import default_cache
from .models import MODELS
from .report import Header, markdown, write
from .runner import Settings, run_model
from .spec import Entry

DESCRIPTION = "Conformance of int8 engines on real third-party float models (benchmarks/conformance/models.py)."


def versions() -> dict[str, str]:
    """The libraries a result depends on, as installed."""
    import subprocess
    from importlib.metadata import PackageNotFoundError, version

    found = {}
    commit = subprocess.run(["git", "-C", str(Path(__file__).resolve().parent), "rev-parse", "--short", "HEAD"],
                            capture_output=True, text=True).stdout.strip()
    for name in ("edgepick", "onnxruntime", "openvino", "nncf", "onnx", "numpy", "opencv-python-headless"):
        try:
            found[name] = version(name).split("-")[0]
        except PackageNotFoundError:
            pass
    if commit and "edgepick" in found:
        found["edgepick"] += f" ({commit})"
    return found


def listing(table: Sequence[Entry]) -> str:
    lines = ["| model | family | source | licence | input | metric | pinned (engine: minimum) |", "|---|---|---|---|---|---|---|"]
    for e in table:
        pins = ", ".join(f"{r.engine}: {100 * r.minimum:.2f}%" for r in e.references) or "-"
        lines.append(f"| {e.name} | {e.family} | {e.origin} | {e.licence} | {list(e.input_shape)} | {e.metric.name} | {pins} |")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None, table: Sequence[Entry] = MODELS,
         engines: Sequence[engine_table.Engine] = engine_table.ENGINES) -> int:
    """Run the conformance table (TABLE, ENGINES: the tests give their own); returns the exit status."""
    ap = argparse.ArgumentParser(prog="benchmarks/conformance.py", description=DESCRIPTION)
    ap.add_argument("--only", default="", help="comma-separated model names (default: all)")
    ap.add_argument("--engines", default="", help=f"comma-separated, of {', '.join(e.name for e in engines)} "
                    "(default: all; fp32 on each runtime used is always run)")
    ap.add_argument("--cache", type=Path, default=None, help=f"where fetched files are kept (default {default_cache()})")
    ap.add_argument("--calib", type=int, default=32, help="calibration inputs per model")
    ap.add_argument("--test", type=int, default=16, help="test inputs per model (other inputs than the calibration's)")
    ap.add_argument("--runs", type=int, default=20, help="timed runs per engine")
    ap.add_argument("--repeats", type=int, default=1, help="time every engine this many times, one timing after "
                    "another: the report gives the median p50 and speed-up and the speed-ups' range (default 1)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", type=Path, default=None, help="also write the report to this .md (and its .csv, .json, .png)")
    ap.add_argument("--save", action="store_true", help="also write it under benchmarks/results/conformance/")
    ap.add_argument("--list", action="store_true", help="print the table and exit")
    args = ap.parse_args(argv)
    if args.list:
        print(listing(table))
        return 0
    if args.repeats < 1:
        ap.error(f"--repeats: {args.repeats}; give 1 or more")
    names = [n for n in args.only.split(",") if n]
    unknown = [n for n in names if n not in {e.name for e in table}]
    if unknown:
        ap.error(f"--only: unknown {', '.join(unknown)} (see --list)")
    chosen = [e for e in table if not names or e.name in names]
    settings = Settings(engines=engine_table.select([n for n in args.engines.split(",") if n] or None, engines),
                        cache=args.cache or default_cache(), calib=args.calib, test=args.test, runs=args.runs,
                        threads=args.threads, repeats=args.repeats)
    log = lambda text: print(text, file=sys.stderr, flush=True)  # noqa: E731
    t0 = time.perf_counter()
    results = [run_model(entry, settings, log) for entry in chosen]
    command = "python benchmarks/conformance.py " + shlex.join(argv if argv is not None else sys.argv[1:])
    header = Header(command=command.strip(), machine=machine_line(), versions=versions(), calib=args.calib,
                    test=args.test, runs=args.runs, threads=args.threads, repeats=args.repeats,
                    date=f"{date.today().isoformat()}, {time.perf_counter() - t0:.0f} s wall")
    targets = [args.out] if args.out else []
    if args.save:
        suffix = "-" + "-".join(names) if names and len(chosen) < len(table) else ""
        targets.append(results_file(RESULTS, "conformance", machine_slug() + suffix))
    print(markdown(results, header))
    for md in targets:
        for path in write(results, header, md):
            log(f"written to {path}")
    regressed = [(m.name, e.engine) for m in results for e in m.regressions]
    if regressed:
        log("regressed against the pinned references: " + ", ".join(f"{m}/{e}" for m, e in regressed))
    return 1 if regressed else 0
