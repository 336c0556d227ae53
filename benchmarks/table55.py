"""Thesis Tables 5.5 and 5.6, regenerated: synthetic data, one float run, static PTQ, QaT from
scratch, hybrid-QaT 1/5/10% from the float run's kept epochs, then `edgepick bench`.

    python benchmarks/table55.py --quick             # minutes on 2 CPU cores (scaled down, stated in the output)
    python benchmarks/table55.py --setting short     # 4000/1000/100 at 640x480, 100 epochs of 160 images (GPU)
    python benchmarks/table55.py                     # the full setting: 4000/1000/100 at 640x480, 100 epochs (GPU)

Phases can be split over several runs with --work DIR --only PHASES (synth, float, fp32, static,
qat, hybrid, bench): a phase whose output is already in DIR is kept, with its recorded time.
Writes benchmarks/results/table55/<date>-<machine>[-<setting>].md (+ .png) with the machine, the
versions, the settings, the commands, the wall time of every phase and the tables
(edgepick/bench/table55.py).
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from edgepick.bench.table55 import PHASES, SETTINGS, make_table55  # noqa: E402
from edgepick.machine import results_file  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--setting", default="full", choices=sorted(SETTINGS))
    ap.add_argument("--quick", action="store_true", help="same as --setting quick")
    ap.add_argument("--work", default=None,
                    help="work folder, kept and resumed (default: a fresh one under /tmp, removed at the end)")
    ap.add_argument("--only", default=None, help=f"comma-separated phases to run now, of: {','.join(PHASES)}")
    ap.add_argument("--results", default=str(Path(__file__).parent / "results"))
    ap.add_argument("--device", default="auto", choices=["auto", "cpu", "cuda"])
    args = ap.parse_args()
    setting = SETTINGS["quick" if args.quick else args.setting]
    only = None if args.only is None else {p.strip() for p in args.only.split(",") if p.strip()}
    if only is not None and not only <= set(PHASES):
        ap.error(f"--only takes phases of {','.join(PHASES)}; got {args.only}")

    work = Path(args.work) if args.work else Path(f"/tmp/table55-{os.getpid()}")
    if not args.work and work.exists():
        shutil.rmtree(work)
    cmd = f"python benchmarks/table55.py --setting {setting.name}" + (f" --only {args.only}" if only else "")
    table = make_table55(work, setting, args.device, cmd, echo=lambda line: print(line, file=sys.stderr, flush=True),
                         only=only)
    if table is not None:
        md = results_file(args.results, "table55", table["name"])
        md.parent.mkdir(parents=True, exist_ok=True)
        md.write_text(table["markdown"])
        shutil.copy(table["png"], md.with_suffix(".png"))
        print(table["markdown"])
    if not args.work:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
