"""The grasp step on the scene's true labels: what the pick loop achieves with a perfect
segmentation, the ceiling of the grasp step itself (a synthetic frame carries its true labels)."""

from __future__ import annotations

import time

from edgepick.frames import Frame
from edgepick.runtime.calibration import Calibration
from edgepick.runtime.grasp import Laps, grasp_records
from edgepick.runtime.grasp_config import GraspConfig
from edgepick.runtime.pipeline import Perception, Pipeline


class TruthPipeline(Pipeline):
    """Pipeline's interface, with the frame's true labels in place of a model's."""

    def __init__(self, classes: list[str], calib: Calibration | None = None, cfg: GraspConfig | None = None,
                 profile: bool = False):
        self.calib, self.cfg, self.classes = calib, cfg or GraspConfig(), list(classes)  # no segmenter: no model
        self.profile = profile

    def __call__(self, frame: Frame) -> Perception:
        if frame.labels is None:
            raise ValueError("TruthPipeline needs frames that carry their true labels (a synthetic camera)")
        laps = Laps() if self.profile else None
        t0 = time.perf_counter()
        records = grasp_records(frame.labels, frame.depth, frame.intrinsics, self.classes, self.calib, self.cfg, laps)
        return Perception(frame.labels, records, {"pre": 0.0, "inference": 0.0, "post": 0.0,
                                                  "grasp": 1000 * (time.perf_counter() - t0)}, laps.ms if laps else {})
