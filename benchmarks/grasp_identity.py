"""Whether the grasp step still makes the same decisions: the grasp records of the synthetic cell's
frames (seeds x cycles, 640x480, camera 0.7 m over the table), on the shipped reference model's labels
and on the scenes' true labels, against a digest file written before a change to the grasp step.

    python benchmarks/grasp_identity.py --write benchmarks/results/grasp-identity/records.json [--fixture DIR]
    python benchmarks/grasp_identity.py --check benchmarks/results/grasp-identity/records.json [--save]

A frame's records (docs/contracts.md#grasp-record: every object's class, point, angle, depth, pose,
area, partial, occluded) are compared as a digest of their JSON. A frame whose model labels differ
from those the file was written with (another CPU's int8 kernels may break an arg-max tie) cannot be
compared on the model's labels and is counted apart. --fixture also stores a few of the frames
(the model's labels as PNG, and their full records) for tests/runtime/test_grasp_cell.py, which
checks them in the test suite.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from _common import add_output, emit, machine_line  # noqa: E402

import edgepick.runtime.grasp as grasp_module  # noqa: E402
from edgepick.data.render import CLASSES  # noqa: E402
from edgepick.reference import reference_model  # noqa: E402
from edgepick.runtime.grasp import grasp_records  # noqa: E402
from edgepick.runtime.pipeline import Pipeline  # noqa: E402
from edgepick.runtime.session import Segmenter  # noqa: E402
from edgepick.sim.camera import SynthCamera  # noqa: E402

MOUNT_M = 0.7


def digest(value: object) -> str:
    """A short digest of VALUE's canonical JSON (or of an array's bytes)."""
    data = value.tobytes() if isinstance(value, np.ndarray) else json.dumps(value, sort_keys=True).encode()
    return hashlib.sha256(data).hexdigest()[:16]


def cell_frames(seeds: list[int], cycles: int):
    """(seed, camera, frame) for each of the CYCLES frames of each seed's synthetic cell."""
    for seed in seeds:
        camera = SynthCamera(640, 480, seed=seed, mount_height_m=MOUNT_M)
        for _ in range(cycles):
            yield seed, camera, camera.read()


def evaluate(seeds: list[int], cycles: int, threads: int, count_splits: bool = False) -> list[dict]:
    """Per frame: its name, the digests of the model's labels and of both record lists, the records
    and labels themselves, and (COUNT_SPLITS) how many regions the grasp step split."""
    segmenter = Segmenter(reference_model(), threads=threads)
    rows, pipelines = [], {}
    splits: list[int] = []
    if count_splits:  # count the regions split into two or more objects, to pick the fixture's frames
        split = grasp_module.split_touching

        def counting(*args, **kwargs):
            parts = split(*args, **kwargs)
            splits[-1] += len(parts) > 1
            return parts

        grasp_module.split_touching = counting
    t0 = time.perf_counter()
    for seed, camera, frame in cell_frames(seeds, cycles):  # one Pipeline per seed: its cell's calibration
        pipeline = pipelines.setdefault(seed, Pipeline(segmenter, camera.calibration()))
        splits.append(0)
        seen = pipeline(frame)
        model = [g.to_dict() for g in seen.records]
        truth = [g.to_dict() for g in grasp_records(frame.labels, frame.depth, frame.intrinsics, CLASSES, pipeline.calib)]
        rows.append({"frame": frame.name, "labels": digest(seen.labels), "model": digest(model),
                     "truth": digest(truth), "splits": splits[-1], "label_image": seen.labels,
                     "model_records": model, "truth_records": truth})
        if len(rows) % 50 == 0:
            print(f"{len(rows)} frames, {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    return rows


def write_fixture(rows: list[dict], count: int, out: Path) -> None:
    """COUNT frames for the test suite: half the ones with the most split regions, half spread over the rest."""
    ranked = sorted(rows, key=lambda r: (-r["splits"], -len(r["model_records"]), r["frame"]))
    chosen = ranked[:count // 2]
    rest = ranked[count // 2:]
    chosen += [rest[i] for i in np.linspace(0, len(rest) - 1, count - len(chosen)).astype(int)]
    out.mkdir(parents=True, exist_ok=True)
    frames = []
    for r in sorted(chosen, key=lambda r: r["frame"]):
        if not cv2.imwrite(str(out / f"{r['frame']}.png"), r["label_image"]):
            raise OSError(f"could not write {out / r['frame']}.png")
        frames.append({"frame": r["frame"], "labels": f"{r['frame']}.png", "model_records": r["model_records"],
                       "truth_records": r["truth_records"]})
    lines = ",\n".join(json.dumps(f, separators=(",", ":")) for f in frames)  # one frame per line
    (out / "records.json").write_text(f'{{"mount_height_m": {MOUNT_M}, "frames": [\n{lines}\n]}}\n')
    print(f"fixture: {len(frames)} frames in {out}", file=sys.stderr)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    mode = ap.add_mutually_exclusive_group(required=True)
    mode.add_argument("--write", type=Path, help="write the digest file (before changing the grasp step)")
    mode.add_argument("--check", type=Path, help="compare with this digest file")
    ap.add_argument("--seeds", type=int, default=10, help="cell seeds 0..N-1")
    ap.add_argument("--cycles", type=int, default=50, help="frames per seed")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--fixture", type=Path, default=None, help="with --write: also store test frames here")
    ap.add_argument("--fixture-frames", type=int, default=40)
    add_output(ap)
    args = ap.parse_args()

    rows = evaluate(list(range(args.seeds)), args.cycles, args.threads, count_splits=args.fixture is not None)
    keys = ("frame", "labels", "model", "truth")
    if args.write:
        args.write.parent.mkdir(parents=True, exist_ok=True)
        args.write.write_text(json.dumps({"model": reference_model().name, "seeds": args.seeds, "cycles": args.cycles,
                                          "frames": [{k: r[k] for k in keys} for r in rows]}, indent=0) + "\n")
        print(f"written to {args.write}", file=sys.stderr)
        if args.fixture:
            write_fixture(rows, args.fixture_frames, args.fixture)
        return
    reference = {f["frame"]: f for f in json.loads(args.check.read_text())["frames"]}
    missing = [r["frame"] for r in rows if r["frame"] not in reference]
    if missing:
        sys.exit(f"{args.check} has no record of {len(missing)} frames (first: {missing[0]}): rerun with its --seeds/--cycles")
    truth_diff = [r["frame"] for r in rows if r["truth"] != reference[r["frame"]]["truth"]]
    same_labels = [r for r in rows if r["labels"] == reference[r["frame"]]["labels"]]
    model_diff = [r["frame"] for r in same_labels if r["model"] != reference[r["frame"]]["model"]]
    lines = ["# Grasp step: the same decisions as before a change", "",
             f"Command: `python benchmarks/grasp_identity.py {' '.join(sys.argv[1:])}`  ",
             f"{machine_line()}; opencv {cv2.__version__}, numpy {np.__version__}; synthetic cell seeds 0-{args.seeds - 1} "
             f"x {args.cycles} frames, 640x480, camera {MOUNT_M} m over the table.", "",
             "| Labels | frames compared | records identical | records differing |", "|---|---|---|---|",
             f"| the scenes' true labels | {len(rows)} | {len(rows) - len(truth_diff)} | {len(truth_diff)} |",
             f"| the reference model's | {len(same_labels)} | {len(same_labels) - len(model_diff)} | {len(model_diff)} |", ""]
    if len(same_labels) < len(rows):
        lines.append(f"{len(rows) - len(same_labels)} frames' model labels differ from those {args.check.name} was "
                     "written with (another CPU's int8 kernels); they are not compared on the model's labels.")
    if truth_diff or model_diff:
        lines.append("Differing frames: " + ", ".join((truth_diff + model_diff)[:20]))
    emit("\n".join(lines) + "\n", args)
    if truth_diff or model_diff:
        sys.exit(1)


if __name__ == "__main__":
    main()
