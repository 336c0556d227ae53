"""Synthetic scene throughput at 640x480 (issue target: >= 20 scenes/s on 2 cores).

    python benchmarks/synth_speed.py [--scenes 204] [--workers 0]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import tempfile
from pathlib import Path

from edgepick.data.synth import SynthConfig, synthesize


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", type=int, default=204)
    ap.add_argument("--workers", type=int, default=0, help="0 = one per core")
    ap.add_argument("--size", default="640x480")
    args = ap.parse_args()
    w, h = (int(v) for v in args.size.split("x"))
    tmp = Path(tempfile.mkdtemp())
    try:
        result = synthesize(tmp / "data", SynthConfig(scenes=args.scenes, width=w, height=h, workers=args.workers),
                            progress=False)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    result.pop("out")
    result.update(cores=os.cpu_count(), cpu=platform.processor() or platform.machine(), size=args.size)
    print(json.dumps(result))


if __name__ == "__main__":
    main()
