"""The grasp step of this checkout against another commit's, on the same cell frames, in one process:
each frame's grasp records made by both in turn (the order alternating), so that a shared machine's
load falls on both alike and a change of 10-20% stands out of the noise that separate runs show.

    python benchmarks/grasp_speed.py --against COMMIT [--against COMMIT ...] [--frames 200] [--repeat 3]
                                     [--threads 2] [--out FILE.md | --save]

Frames: the synthetic cell's (camera 0.7 m over the table, seeds 0, 1, ... 50 frames each), as
benchmarks/runtime_stages.py takes them; labels: the scenes' true ones and the shipped reference
model's (inferred once per frame, before any timing). COMMIT's edgepick package comes from `git
archive` into a temporary folder and is imported beside this checkout's. Each frame's time is the
least of --repeat calls; the report gives p50 / p95 over the frames, the median of the per-frame
ratios, and whether both made the same records on every frame.
"""

from __future__ import annotations

import argparse
import importlib
import io
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from _common import add_output, emit, machine_line  # noqa: E402
from runtime_stages import MOUNT_M, cell_frames  # noqa: E402

REPO = Path(__file__).resolve().parents[1]


def grasp_step_of(commit: str, folder: Path):
    """grasp_records as COMMIT has it: its edgepick package unpacked in FOLDER and imported under its
    own name, then this checkout's imported again (each function keeps its own module's globals)."""
    try:
        tar = subprocess.run(["git", "-C", str(REPO), "archive", commit, "edgepick"], capture_output=True, check=True).stdout
    except subprocess.CalledProcessError as exc:
        sys.exit(f"grasp_speed: error: --against {commit}: {exc.stderr.decode().strip().splitlines()[0]}")
    tarfile.open(fileobj=io.BytesIO(tar)).extractall(folder, filter="data")
    mine = {k: v for k, v in sys.modules.items() if k == "edgepick" or k.startswith("edgepick.")}
    for k in mine:
        del sys.modules[k]
    sys.path.insert(0, str(folder))
    try:
        theirs = importlib.import_module("edgepick.runtime.grasp").grasp_records
    finally:
        sys.path.remove(str(folder))
        for k in [k for k in sys.modules if k == "edgepick" or k.startswith("edgepick.")]:
            del sys.modules[k]
        sys.modules.update(mine)
    return theirs


def as_records(made: list) -> list[dict]:
    """The records a grasp step made, as JSON records: a commit's step may return dicts or Grasps."""
    return [r if isinstance(r, dict) else r.to_dict() for r in made]


def compare(theirs, mine, frames: list, labels: list, calibration, repeat: int) -> tuple[np.ndarray, np.ndarray, int]:
    """(their ms, my ms) per frame, each the least of REPEAT calls, the two taken in turn with the
    first alternating; and on how many frames both made the same records."""
    from edgepick.data.render import CLASSES

    times: list[list[float]] = [[], []]
    same = 0
    for i, (frame, lab) in enumerate(zip(frames, labels)):
        steps = [(0, theirs), (1, mine)] if i % 2 else [(1, mine), (0, theirs)]
        best, made = [float("inf")] * 2, [None, None]
        for _ in range(repeat):
            for k, step in steps:
                t0 = time.perf_counter()
                made[k] = step(lab, frame.depth, frame.intrinsics, CLASSES, calibration)
                best[k] = min(best[k], 1000 * (time.perf_counter() - t0))
        times[0].append(best[0])
        times[1].append(best[1])
        same += as_records(made[0]) == as_records(made[1])
    return np.array(times[0]), np.array(times[1]), same


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--against", required=True, action="append", help="a commit (or branch, tag) to compare with "
                    "(repeatable: each in turn against this checkout)")
    ap.add_argument("--frames", type=int, default=200)
    ap.add_argument("--repeat", type=int, default=3, help="calls per frame and version; the least counts")
    ap.add_argument("--threads", type=int, default=2, help="the reference model's threads (its labels only)")
    add_output(ap)
    args = ap.parse_args()

    for commit in args.against:  # a bad name stops the script before any work
        if subprocess.run(["git", "-C", str(REPO), "rev-parse", "--verify", "-q", f"{commit}^{{commit}}"],
                          capture_output=True).returncode:
            sys.exit(f"grasp_speed: error: --against {commit}: not a commit of {REPO}")
    from edgepick.reference import reference_model
    from edgepick.runtime.grasp import grasp_records
    from edgepick.runtime.session import Segmenter
    from edgepick.sim.camera import SynthCamera

    frames = cell_frames(args.frames)
    calibration = SynthCamera(640, 480, seed=0, mount_height_m=MOUNT_M).calibration()
    segmenter = Segmenter(reference_model(), threads=args.threads)
    sources = {"true labels": [f.labels for f in frames], "reference model's labels": [segmenter.labels(f.rgb) for f in frames]}
    lines = ["# The grasp step against earlier commits, frame by frame in one process", "",
             f"Command: `python benchmarks/grasp_speed.py {' '.join(sys.argv[1:])}`  ",
             f"{machine_line()}; opencv {cv2.__version__}, numpy {np.__version__}; {len(frames)} frames of the synthetic "
             f"cell (640x480, seeds 0-{(len(frames) - 1) // 50}, "
             f"camera {MOUNT_M} m over the table); each frame's time the least of {args.repeat} calls per version, "
             "the two versions taken in turn, the first one alternating. ms over the frames.", "",
             "| Against | Labels | its p50 / p95 | this checkout p50 / p95 | per-frame ratio, median (p5-p95) | "
             "same records |", "|---|---|---|---|---|---|"]
    for commit in args.against:
        with tempfile.TemporaryDirectory() as tmp:
            theirs = grasp_step_of(commit, Path(tmp))
        for source, labels in sources.items():
            old, new, same = compare(theirs, grasp_records, frames, labels, calibration, args.repeat)
            ratio = old / new
            lines.append(f"| {commit} | {source} | {np.percentile(old, 50):.2f} / {np.percentile(old, 95):.2f} | "
                         f"{np.percentile(new, 50):.2f} / {np.percentile(new, 95):.2f} | {np.median(ratio):.2f}x "
                         f"({np.percentile(ratio, 5):.2f}-{np.percentile(ratio, 95):.2f}) | {same} of {len(frames)} |")
    lines += ["", "Ratio: the other commit's time over this checkout's, per frame (above 1: this checkout is faster)."]
    emit("\n".join(lines) + "\n", args)


if __name__ == "__main__":
    main()
