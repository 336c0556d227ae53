"""`edgepick pick`: camera -> segmentation -> grasp records -> target -> plan -> robot, per cycle.

Without `execute` the plan is printed and nothing is sent. Each cycle reports the chosen
object, the frame -> first-command latency, the outcome and, when the camera knows the
scene's truth and the cell's true calibration (the synthetic cell), the grasp point's error
and the cycle's verdict (robot/verdict.py: success, or why not).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import replace
from pathlib import Path

import cv2

from edgepick.errors import ParameterError
from edgepick.frames import Camera, Frame
from edgepick.robot.base import RobotBase
from edgepick.robot.clearance import hand_clearance
from edgepick.robot.cycle import CycleResult, verdicts
from edgepick.robot.envelope import Envelope
from edgepick.robot.grippers import DigitalGripper, RG2Gripper
from edgepick.robot.pick import CommandLog, PickConfig, Step, choose_target, execute
from edgepick.robot.recording import PickCycle, Recorder, SceneChange, StepDone
from edgepick.robot.verdict import Verdict, judge, summarize, undetected
from edgepick.runtime.calibration import Calibration
from edgepick.runtime.grasp import draw_overlay
from edgepick.runtime.grasp_record import Grasp
from edgepick.runtime.pipeline import Pipeline

SUCCESS_M = 0.01  # thesis 5.1.5: a grasp point within 1 cm


def grasp_error_m(record: Grasp, truth: list[dict] | None) -> float | None:
    """Distance from the grasp's 3D point to the nearest true object of its class (camera
    frame); infinity when the scene has no object of that class (a false detection)."""
    point = record.point_camera_m
    if not truth or point is None:
        return None
    same = [t for t in truth if t["class"] == record.cls]
    return min((math.dist(point, t["point_camera_m"]) for t in same), default=math.inf)


def judge_cycle(result: CycleResult, seen: list[Grasp], frame: Frame, cfg: PickConfig,
                truth_cal: Calibration | None) -> CycleResult:
    """RESULT with what it says about its choice: the grasp point's error against the scene's
    truth and, in the synthetic cell (TRUTH_CAL, the cell's true calibration), the verdict
    (robot/verdict.py). SEEN: every grasp of the frame."""
    record = result.chosen
    if record is None:
        if truth_cal is None or frame.truth is None:
            return result
        wanted = [r for r in seen if not cfg.classes or r.cls in cfg.classes]
        return replace(result, verdict=Verdict(False, "unreachable" if wanted else "no object seen"),
                       undetected=undetected(seen, frame.truth))
    err = grasp_error_m(record, frame.truth)
    false_detection = err is not None and math.isinf(err)
    result = replace(result, grasp_error_m=None if err is None or false_detection else round(err, 4),
                     within_1cm=None if err is None else err <= SUCCESS_M,
                     note=f"no {record.cls} in the scene's truth (false detection)" if false_detection else None)
    if truth_cal is not None and frame.truth is not None:
        result = replace(result, verdict=judge(record, frame, truth_cal), undetected=undetected(seen, frame.truth))
    return result


class Lookahead:
    """The next frame, read and segmented on a worker thread while the arm finishes the cycle
    (`pick --overlap`): started once the arm has left the pick area (Step.clears_view), taken by
    the next cycle, which then plans at once."""

    def __init__(self, camera: Camera, pipeline: Pipeline):
        self.camera, self.pipeline = camera, pipeline
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="edgepick-lookahead")
        self._pending: Future | None = None

    def start(self) -> None:
        """Read and segment the next frame from now on (once per cycle)."""
        if self._pending is None:
            self._pending = self._pool.submit(self._see)

    def _see(self):
        frame = self.camera.read()
        return frame, time.perf_counter(), self.pipeline(frame)

    def take(self):
        """(frame, the time it was read, its Perception), or None when none was started; raises
        what reading or segmenting it raised (StopIteration: the camera has no more frames)."""
        pending, self._pending = self._pending, None
        return None if pending is None else pending.result()

    def close(self) -> None:
        """Wait for a frame still being read or segmented, and stop the worker."""
        self._pool.shutdown(wait=True, cancel_futures=True)


def run_cycles(camera: Camera, pipeline: Pipeline, robot: RobotBase | None,
               gripper: DigitalGripper | RG2Gripper | None, *, cfg: PickConfig, cycles: int, log: CommandLog,
               overlay_dir: str | Path | None = None, echo: Callable[[str], object] = print,
               truth_cal: Calibration | None = None, overlap: bool = False,
               recorder: Recorder | None = None, physics: Callable[[Grasp, Frame], Verdict] | None = None,
               done: list[CycleResult] | None = None,
               after: Callable[[CycleResult, Grasp | None, Frame], SceneChange] | None = None,
               first: int = 1) -> list[CycleResult]:
    """Run up to `cycles` pick cycles (robot None = plan only). Stops early when the robot halts
    (a failed gripper halts it too). Each plan passes the envelope and, with a robot, the
    controller's own safety limits before its first command. TRUTH_CAL (the synthetic cell's true
    calibration) lets each cycle be judged against the truth. ECHO gets each cycle's line.
    OVERLAP (with a robot): the next frame is read and segmented while the arm places the object
    and returns (Lookahead), so the arm waits only for the plan; the cell's camera must then not
    see the arm, nor the part it holds, from the place approach pose on. RECORDER gets each cycle
    once its commands are sent (robot/recording.py). PHYSICS (the synthetic cell: sim/physics.py's
    judge) gives each judged cycle a second verdict, "physics", after its commands. DONE, when given, is
    the list each finished cycle's result is appended to (and returned): the caller's own, which still
    holds the cycles run when Ctrl-C or SIGTERM ends the loop half-way. AFTER (a clutter-removal round,
    sim/clutter.py) is called with each cycle's result, chosen record and frame once it is judged: the
    scene changes for the next frame, and the run ends where its SceneChange says the round ended (a
    scene that changes after a cycle cannot be read ahead: not with OVERLAP). FIRST: the first cycle's
    number (rounds number their cycles on from the round before)."""
    if after is not None and overlap:
        raise ParameterError("{overlap}: the next frame shows the scene the cycle leaves behind, so it cannot be "
                             "read while the cycle goes on", overlap=overlap)
    ahead = Lookahead(camera, pipeline) if overlap and robot is not None else None
    try:
        return _cycles(camera, pipeline, robot, gripper, cfg, range(first, first + cycles), log, overlay_dir, echo,
                       truth_cal, ahead, recorder, physics, [] if done is None else done, after)
    finally:
        if ahead is not None:
            ahead.close()


def _cycles(camera: Camera, pipeline: Pipeline, robot: RobotBase | None, gripper: DigitalGripper | RG2Gripper | None,
            cfg: PickConfig, cycles: range, log: CommandLog, overlay_dir: str | Path | None, echo: Callable[[str], object],
            truth_cal: Calibration | None, ahead: Lookahead | None, recorder: Recorder | None,
            physics: Callable[[Grasp, Frame], Verdict] | None, results: list[CycleResult],
            after: Callable[[CycleResult, Grasp | None, Frame], SceneChange] | None) -> list[CycleResult]:
    """run_cycles' loop, appending to RESULTS. Per cycle, besides the outcome: plan_ms (frame read ->
    checked plan), frame_to_command_ms (-> the first command sent), frame_to_frame_ms (since the
    previous frame was read) and arm_wait_ms (the previous cycle's last command done -> this one's
    first sent)."""
    envelope = robot.envelope if robot is not None else Envelope()
    limits = robot.limits_reason if robot is not None else None  # plan only: no controller to ask
    if overlay_dir:
        Path(overlay_dir).mkdir(parents=True, exist_ok=True)
    previous_frame = arm_free = None
    for cycle in cycles:
        try:
            early = ahead.take() if ahead is not None else None
            if early is None:
                frame: Frame = camera.read()
                t0 = time.perf_counter()
                seen = pipeline(frame)
            else:
                frame, t0, seen = early
        except StopIteration:
            echo(f"cycle {cycle}: the camera has no more frames")
            break
        start = robot.tcp_pose() if robot is not None else None  # plan only: from the home pose
        clear = hand_clearance(frame.depth, frame.intrinsics, pipeline.calib, cfg.hand) \
            if cfg.hand is not None and pipeline.calib is not None else None
        record, plan, note = choose_target(seen.records, envelope, cfg, start, limits, clear)
        steps: list[StepDone] = []
        t_plan = time.perf_counter()
        result = CycleResult(cycle, frame.name, len(seen.records), seen.ms, round(1000 * (t_plan - t0), 2),
                             "skipped" if record is None else "planned", note if record is None else None, frame.scene,
                             None if previous_frame is None else round(1000 * (t0 - previous_frame), 2), record,
                             plan=plan)
        previous_frame = t0
        if record is None:
            log.write(cycle=cycle, command="none", target=None, result=f"skipped: {note}")
        result = judge_cycle(result, seen.records, frame, cfg, truth_cal)
        if record is not None and robot is not None:
            motion0 = getattr(robot, "motion_s", 0.0)
            first: dict[str, float] = {}

            def mark(first=first):
                first.setdefault("t", time.perf_counter())

            robot.on_send = mark
            next_frame = ahead.start if ahead is not None and cycle < cycles[-1] else None
            on_step = _step_recorder(robot, steps) if recorder is not None else None
            stopped = execute(plan, robot, gripper, log, cycle, cfg, on_clear=next_frame, on_step=on_step)
            robot.on_send = None
            sent, commands_done = first.get("t"), time.perf_counter()
            verdict = result.verdict.stopped() if stopped is not None and result.verdict is not None else result.verdict
            result = replace(result, outcome="done" if stopped is None else "stopped", reason=stopped, verdict=verdict,
                             frame_to_command_ms=None if sent is None else round(1000 * (sent - t0), 2),
                             arm_wait_ms=None if sent is None or arm_free is None else round(1000 * (sent - arm_free), 2),
                             motion_s=round(getattr(robot, "motion_s", 0.0) - motion0, 3))
            arm_free = commands_done
        if physics is not None and result.verdict is not None:  # after the commands, as the overlay
            result = replace(result, physics=physics_verdict(result, frame, physics))
        change = after(result, record, frame) if after is not None else None
        if change is not None:
            result = replace(result, round=change.summary())
        if overlay_dir:  # after the robot's commands: not part of the frame -> command latency
            cv2.imwrite(str(Path(overlay_dir) / f"cycle_{cycle:03d}.png"),
                        draw_overlay(frame.rgb, [record] if record else seen.records))
        results.append(result)
        line = cycle_line(result)
        if recorder is not None:  # after the robot's commands, written on the recorder's thread
            frame_ns = time.time_ns() - int(1e9 * (time.perf_counter() - t0))
            recorder.add(PickCycle(cycle, frame, frame_ns, seen.labels, seen.records, record, plan, start, result,
                                   steps, line, change))
        echo(line)
        if robot is not None and robot.halted:
            break  # the caller reports it once
        if change is not None and change.ended:
            break
    return results


def physics_verdict(result: CycleResult, frame: Frame, physics: Callable[[Grasp, Frame], Verdict]) -> Verdict:
    """The physics check's verdict on a judged cycle: its own on a grasp that was carried out, the
    geometric one where nothing was chosen, a failure where the robot stopped."""
    if result.verdict is None:
        raise ValueError(f"cycle {result.cycle} was not judged: the physics check follows the geometric rule")
    if result.chosen is None:
        return Verdict(result.verdict.success, result.verdict.failure)
    if result.outcome == "stopped":
        return Verdict(False, "robot stopped")
    return physics(result.chosen, frame)


def _step_recorder(robot: RobotBase, steps: list[StepDone]) -> Callable[[Step, str], None]:
    """execute's on_step for a recording: each step's time, and the TCP the robot reports after it."""
    def on_step(step: Step, result: str) -> None:
        try:
            reported = robot.tcp_pose()
        except Exception:  # noqa: BLE001 - a lost link: the step is recorded without a pose
            reported = None
        steps.append(StepDone(time.time_ns(), step, reported, result))

    return on_step


def cycles_summary(results: list[CycleResult]) -> dict:
    """What `pick` and the demo report over their cycles: count, done, within 1 cm, median grasp
    error and frame -> command latency, and (synthetic cell) grasp success and failures by kind,
    of the geometric verdict and, where it ran, the physics check ("physics")."""
    def median(values: list[float | None]) -> float | None:
        known = sorted(v for v in values if v is not None)
        return known[len(known) // 2] if known else None

    error = median([r.grasp_error_m for r in results])
    return {"cycles": len(results), "done": sum(r.outcome == "done" for r in results),
            "within_1cm": sum(bool(r.within_1cm) for r in results),
            "grasp_error_mm_median": None if error is None else round(1000 * error, 2),
            **summarize(verdicts(results)),
            **({"physics": summarize(verdicts(results, "physics"))} if any(r.physics is not None for r in results) else {}),
            "frame_to_command_ms_median": median([r.frame_to_command_ms for r in results]),
            "frame_to_frame_ms_median": median([r.frame_to_frame_ms for r in results]),
            "arm_wait_ms_median": median([r.arm_wait_ms for r in results])}


def cycle_line(r: CycleResult) -> str:
    """One cycle's result as the line `pick` prints: the target, outcome, grasp error, latency and verdict."""
    if r.chosen is None:
        return f"cycle {r.cycle}: nothing to pick ({r.reason}){_verdict(r)}"
    err = "" if r.grasp_error_m is None else \
        f", grasp error {1000 * r.grasp_error_m:.1f} mm ({'within' if r.within_1cm else 'NOT within'} 1 cm)"
    if r.note:
        err += f", {r.note}"
    lat = f", frame->command {r.frame_to_command_ms:.0f} ms" if r.frame_to_command_ms is not None else ""
    tail = "" if r.outcome in ("done", "planned") else f": {r.reason}"
    return f"cycle {r.cycle}: {r.target} at {list(r.chosen.pixel)} -> {r.outcome}{err}{lat}{tail}{_verdict(r)}"


def _verdict(r: CycleResult) -> str:
    """The line's verdict tail ('; verdict: ...'), empty for a cycle that was not judged."""
    v = r.verdict
    if v is None:
        return ""
    errors = [f"{1000 * v.position_error_m:.1f} mm"] if v.position_error_m is not None else []
    errors += [f"{v.angle_error_deg:.0f} deg"] if v.angle_error_deg is not None else []
    detail = f" ({', '.join(errors)})" if errors else ""
    line = f"; verdict: success{detail}" if v.success else f"; verdict: FAILED, {v.failure}{detail}"
    p = r.physics
    if p is not None:
        why = f" ({p.note})" if p.note else ""
        line += "; physics: success" if p.success else f"; physics: FAILED, {p.failure}{why}"
    return line
