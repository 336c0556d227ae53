"""CycleResult: what one pick cycle did (robot/loop.py) and, in the synthetic cell, how it was judged.
Its `to_dict()` is the cycle as `pick` prints it among its "results" and a recording keeps it
(docs/contracts.md#recordings, `result_json`)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass

from edgepick.robot.pick import Step
from edgepick.robot.verdict import Verdict
from edgepick.runtime.grasp_record import Grasp

OUTCOMES = ("skipped", "planned", "done", "stopped")  # nothing chosen; a plan only; carried out; the robot stopped


@dataclass(frozen=True)
class CycleResult:
    """One cycle, checked on creation: nothing is chosen exactly when it is skipped, a plan is kept
    when it is only planned, and the robot's times belong to a cycle it carried out."""

    cycle: int
    frame: str  # the frame's name
    objects: int  # how many grasps the frame gave
    stage_ms: dict[str, float]  # the pipeline's stages
    plan_ms: float  # frame read -> checked plan
    outcome: str  # OUTCOMES
    reason: str | None = None  # skipped: why nothing was chosen; done or stopped: why the robot stopped (None: it did not)
    scene: dict | None = None  # the synthetic scene's conditions (its light)
    frame_to_frame_ms: float | None = None  # since the previous cycle's frame was read
    chosen: Grasp | None = None
    grasp_error_m: float | None = None  # the chosen grasp's 3D point to the nearest true object of its class
    within_1cm: bool | None = None
    note: str | None = None  # a false detection: no object of the chosen class in the scene
    verdict: Verdict | None = None  # the geometric rule's (robot/verdict.py), when the cycle was judged
    undetected: int | None = None  # the scene's objects no grasp found, when the cycle was judged
    plan: tuple[Step, ...] = ()  # planned: the steps it would have sent
    frame_to_command_ms: float | None = None  # -> the first command sent
    arm_wait_ms: float | None = None  # the previous cycle's last command done -> this one's first sent
    motion_s: float | None = None  # the arm's motion time over the cycle
    physics: Verdict | None = None  # the physics check's (sim/physics.py), when it ran
    round: dict | None = None  # a clutter-removal round's pick (robot/recording.py SceneChange.summary)

    def __post_init__(self) -> None:
        if self.outcome not in OUTCOMES:
            raise ValueError(f"outcome {self.outcome!r}: not one of {OUTCOMES}")
        if (self.chosen is None) != (self.outcome == "skipped"):
            raise ValueError(f"cycle {self.cycle}: a grasp is chosen exactly when the cycle is not skipped")
        if self.chosen is not None and self.chosen.pose_robot is None:
            raise ValueError(f"cycle {self.cycle}: the chosen {self.chosen.cls} has no robot pose")
        if (self.verdict is None) != (self.undetected is None) or (self.physics is not None and self.verdict is None):
            raise ValueError(f"cycle {self.cycle}: a judged cycle has its verdict and its undetected objects")
        object.__setattr__(self, "plan", tuple(self.plan))

    @property
    def target(self) -> str | None:
        """The chosen object's class (None: nothing chosen)."""
        return None if self.chosen is None else self.chosen.cls

    @property
    def carried_out(self) -> bool:
        """Whether a robot carried the cycle's commands out (done, or stopped on the way)."""
        return self.outcome in ("done", "stopped")

    def judged(self, rule: str = "verdict") -> Verdict | None:
        """The verdict of RULE: "verdict" (the geometric rule) or "physics" (the physics check)."""
        if rule not in ("verdict", "physics"):
            raise ValueError(f"rule {rule!r}: 'verdict' or 'physics'")
        return self.verdict if rule == "verdict" else self.physics

    def to_dict(self) -> dict:
        """The cycle as `pick` prints it, its keys in the order they were always printed in."""
        out: dict = {"cycle": self.cycle, "frame": self.frame, "objects": self.objects, "stage_ms": self.stage_ms,
                     "plan_ms": self.plan_ms}
        if self.scene is not None:
            out["scene"] = self.scene
        if self.frame_to_frame_ms is not None:
            out["frame_to_frame_ms"] = self.frame_to_frame_ms
        if self.chosen is None:
            out.update(outcome=self.outcome, reason=self.reason, **self._judged())
        else:
            out.update(target=self.chosen.cls, pixel=list(self.chosen.pixel), pose_robot=list(self.chosen.chosen_pose()),
                       grasp_error_m=self.grasp_error_m, within_1cm=self.within_1cm)
            if self.note is not None:
                out["note"] = self.note
            out.update(self._judged())
            if self.outcome == "planned":
                out.update(outcome=self.outcome, plan=[asdict(s) for s in self.plan])
            else:
                for name in ("frame_to_command_ms", "arm_wait_ms"):
                    if getattr(self, name) is not None:
                        out[name] = getattr(self, name)
                out.update(motion_s=self.motion_s, outcome=self.outcome, reason=self.reason)
        if self.physics is not None:
            out["physics"] = self.physics.to_dict()
        if self.round is not None:
            out["round"] = self.round
        return out

    def _judged(self) -> dict:
        return {} if self.verdict is None else {"verdict": self.verdict.to_dict(), "undetected": self.undetected}


def verdicts(results: Sequence[CycleResult], rule: str = "verdict") -> list[Verdict]:
    """The verdicts of RULE ("verdict": the geometric rule; "physics": the physics check) of the judged
    cycles among RESULTS, for robot/verdict.py's summarize."""
    return [v for v in (r.judged(rule) for r in results) if v is not None]
