"""Synthetic scene throughput at 640x480 (target: >= 20 scenes/s on 2 cores).

    python benchmarks/synth_speed.py [--scenes 204] [--workers 0]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from edgepick.data.render import SceneRenderer
from edgepick.data.synth import _PNG_FAST, _PNG_RLE, SynthConfig, synthesize
from edgepick.geometry import Intrinsics, Size


def per_scene_ms(width: int, height: int, scenes: int = 20) -> dict:
    """Median render and PNG-encode milliseconds of one scene in this process (one core)."""
    cv2.setNumThreads(1)
    renderer = SceneRenderer(Intrinsics.d415(width, height))
    render, encode = [], []
    for i in range(scenes):
        t0 = time.perf_counter()
        scene = renderer.render(np.random.default_rng([0, 0, i]))
        t1 = time.perf_counter()
        cv2.imencode(".png", scene.rgb[..., ::-1], _PNG_FAST)
        cv2.imencode(".png", scene.depth, _PNG_FAST)
        cv2.imencode(".png", scene.mask, _PNG_RLE)
        render.append(t1 - t0)
        encode.append(time.perf_counter() - t1)
    return {"render_ms_p50": round(1000 * float(np.median(render)), 1),
            "png_ms_p50": round(1000 * float(np.median(encode)), 1)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", type=int, default=204)
    ap.add_argument("--workers", type=int, default=0, help="0 = one per core")
    ap.add_argument("--size", default="640x480")
    args = ap.parse_args()
    size = Size.parse(args.size)
    w, h = size.width, size.height
    tmp = Path(tempfile.mkdtemp())
    try:
        result = synthesize(tmp / "data", SynthConfig(scenes=args.scenes, width=w, height=h, workers=args.workers),
                            progress=False)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    result.pop("out")
    result.update(cores=os.cpu_count(), cpu=platform.processor() or platform.machine(), size=args.size,
                  one_core=per_scene_ms(w, h))
    print(json.dumps(result))


if __name__ == "__main__":
    main()
