"""Frame -> labels -> grasp records, with per-stage milliseconds (the runtime's hot path).

Stages as the thesis's Table 5.6 counts them: pre (resize to the model), inference
(onnxruntime), post (labels back to the frame), grasp (filters, moments, depth, pose).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from edgepick.frames import Frame
from edgepick.runtime.calibration import Calibration
from edgepick.runtime.grasp import Laps, grasp_records
from edgepick.runtime.grasp_config import GraspConfig
from edgepick.runtime.grasp_record import Grasp
from edgepick.runtime.session import Segmenter

STAGES = ("pre", "inference", "post", "grasp")


@dataclass
class Perception:
    labels: np.ndarray  # class ids at the frame's resolution
    records: list[Grasp]  # largest first
    ms: dict[str, float] = field(default_factory=dict)  # per stage
    grasp_ms: dict[str, float] = field(default_factory=dict)  # per sub-step of the grasp stage (Laps.STEPS), profiling only


class Pipeline:
    """One segmentation session plus the grasp step; built once, called per frame. PROFILE also
    times the grasp step's sub-steps (Perception.grasp_ms)."""

    def __init__(self, segmenter: Segmenter, calib: Calibration | None = None, cfg: GraspConfig | None = None,
                 profile: bool = False):
        self.segmenter, self.calib, self.cfg, self.profile = segmenter, calib, cfg or GraspConfig(), profile
        self.classes = segmenter.info.classes

    def __call__(self, frame: Frame) -> Perception:
        t0 = time.perf_counter()
        image = self.segmenter.prepare(frame.rgb)
        t1 = time.perf_counter()
        small = self.segmenter.infer(image)
        t2 = time.perf_counter()
        labels = self.segmenter.restore(small, frame.rgb.shape[:2])
        t3 = time.perf_counter()
        laps = Laps() if self.profile else None
        records = grasp_records(labels, frame.depth, frame.intrinsics, self.classes, self.calib, self.cfg, laps)
        t4 = time.perf_counter()
        ms = dict(zip(STAGES, (1000 * (b - a) for a, b in ((t0, t1), (t1, t2), (t2, t3), (t3, t4)))))
        return Perception(labels, records, ms, laps.ms if laps else {})


def median_ms(runs: list[dict[str, float]]) -> dict[str, float]:
    """Per-stage medians of several runs, plus 'outside_inference' and 'total'."""
    out = {s: float(np.median([r[s] for r in runs])) for s in runs[0]}
    out["outside_inference"] = float(np.median([sum(v for k, v in r.items() if k != "inference") for r in runs]))
    out["total"] = float(np.median([sum(r.values()) for r in runs]))
    return {k: round(v, 3) for k, v in out.items()}
