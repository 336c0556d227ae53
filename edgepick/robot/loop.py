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
from dataclasses import dataclass, replace
from pathlib import Path

import cv2

from edgepick.errors import ParameterError
from edgepick.frames import Camera, Frame
from edgepick.robot.base import RobotBase
from edgepick.robot.clearance import hand_clearance
from edgepick.robot.cycle import CycleResult, verdicts
from edgepick.robot.envelope import Envelope
from edgepick.robot.grippers import DigitalGripper, RG2Gripper
from edgepick.robot.pick import CommandLog, PickConfig, Step, carry_path, choose_target, execute
from edgepick.robot.recording import PickCycle, Recorder, SceneChange, StepDone
from edgepick.robot.verdict import Verdict, judge, summarize, undetected
from edgepick.runtime.calibration import Calibration
from edgepick.runtime.grasp import draw_overlay
from edgepick.runtime.grasp_record import Grasp
from edgepick.runtime.pipeline import Perception, Pipeline

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


@dataclass(frozen=True)
class Cell:
    """What the pick loop drives: the camera and the pipeline that sees through it, the arm and its
    gripper (None: plan only), the command log, and where the cycles also go: a recorder, and in
    the synthetic cell its true calibration (TRUTH_CAL: each cycle judged against the scene's truth)
    and the physics check (PHYSICS: sim/physics.py's judge, a second verdict after the commands: the
    chosen grasp, the frame, and the plan's carry_path)."""

    camera: Camera
    pipeline: Pipeline
    robot: RobotBase | None
    gripper: DigitalGripper | RG2Gripper | None
    log: CommandLog
    truth_cal: Calibration | None = None
    recorder: Recorder | None = None
    physics: Callable[[Grasp, Frame, list[list[float]]], Verdict] | None = None


def run_cycles(cell: Cell, *, cfg: PickConfig, cycles: int, overlay_dir: str | Path | None = None,
               echo: Callable[[str], object] = print, overlap: bool = False, done: list[CycleResult] | None = None,
               after: Callable[[CycleResult, Grasp | None, Frame], SceneChange] | None = None,
               first: int = 1) -> list[CycleResult]:
    """Run up to `cycles` pick cycles in CELL (its robot None = plan only). Stops early when the robot
    halts (a failed gripper halts it too). Each plan passes the envelope and, with a robot, the
    controller's own safety limits before its first command. ECHO gets each cycle's line.
    OVERLAP (with a robot): the next frame is read and segmented while the arm places the object
    and returns (Lookahead), so the arm waits only for the plan; the cell's camera must then not
    see the arm, nor the part it holds, from the place approach pose on. The cell's recorder gets each
    cycle once its commands are sent (robot/recording.py). DONE, when given, is the list each finished
    cycle's result is appended to (and returned): the caller's own, which still holds the cycles run
    when Ctrl-C or SIGTERM ends the loop half-way. AFTER (a clutter-removal round, sim/clutter.py) is
    called with each cycle's result, chosen grasp and frame once it is judged: the scene changes for the
    next frame, and the run ends where its SceneChange says the round ended (a scene that changes after
    a cycle cannot be read ahead: not with OVERLAP). FIRST: the first cycle's number (rounds number
    their cycles on from the round before)."""
    if after is not None and overlap:
        raise ParameterError("{overlap}: the next frame shows the scene the cycle leaves behind, so it cannot be "
                             "read while the cycle goes on", overlap=overlap)
    ahead = Lookahead(cell.camera, cell.pipeline) if overlap and cell.robot is not None else None
    try:
        loop = _Loop(cell, cfg, overlay_dir, echo, ahead, after)
        return loop.run(range(first, first + cycles), [] if done is None else done)
    finally:
        if ahead is not None:
            ahead.close()


class _Loop:
    """run_cycles' loop over one cell: per cycle a frame perceived, a grasp chosen and planned, the plan
    carried out, the cycle judged, and reported. Besides the outcome each cycle times plan_ms (frame
    read -> checked plan), frame_to_command_ms (-> the first command sent), frame_to_frame_ms (since
    the previous frame was read) and arm_wait_ms (the previous cycle's last command done -> this
    one's first sent)."""

    def __init__(self, cell: Cell, cfg: PickConfig, overlay_dir: str | Path | None, echo: Callable[[str], object],
                 ahead: Lookahead | None, after: Callable[[CycleResult, Grasp | None, Frame], SceneChange] | None):
        self.cell, self.cfg, self.overlay_dir, self.echo, self.ahead, self.after = cell, cfg, overlay_dir, echo, ahead, after
        self.envelope = cell.robot.envelope if cell.robot is not None else Envelope()
        self.limits = cell.robot.limits_reason if cell.robot is not None else None  # plan only: no controller to ask
        self.previous_frame: float | None = None
        self.arm_free: float | None = None
        self.tried: list[tuple[float, ...]] = []  # on one table: where the carried-out picks went (choose_target's TRIED)
        if overlay_dir:
            Path(overlay_dir).mkdir(parents=True, exist_ok=True)

    def run(self, cycles: range, results: list[CycleResult]) -> list[CycleResult]:
        """Each of CYCLES in turn, appended to RESULTS, until the camera has no more frames, the robot
        halts or a round ends."""
        robot = self.cell.robot
        for cycle in cycles:
            perceived = self.perceive()
            if perceived is None:
                self.echo(f"cycle {cycle}: the camera has no more frames")
                break
            frame, t0, seen = perceived
            start = robot.tcp_pose() if robot is not None else None  # plan only: from the home pose
            steps: list[StepDone] = []
            result = self.choose(cycle, frame, t0, seen, start)
            result = self.act(result, t0, steps, read_ahead=cycle < cycles[-1])
            if result.chosen is not None and result.carried_out and self.cell.camera.same_table:
                self.tried.append(result.chosen.chosen_pose()[:3])
            result, change = self.judge(result, frame)
            self.report(result, frame, t0, seen, start, steps, change, results)
            if robot is not None and robot.halted:
                break  # the caller reports it once
            if change is not None and change.ended:
                break
        return results

    def perceive(self) -> tuple[Frame, float, Perception] | None:
        """The next frame, when it was read, and what the pipeline saw in it: read ahead while the cycle
        before went on, or now. None: the camera has no more frames."""
        try:
            early = self.ahead.take() if self.ahead is not None else None
            if early is not None:
                return early
            frame: Frame = self.cell.camera.read()
            t0 = time.perf_counter()
            return frame, t0, self.cell.pipeline(frame)
        except StopIteration:
            return None

    def choose(self, cycle: int, frame: Frame, t0: float, seen: Perception, start: list[float] | None) -> CycleResult:
        """The preferred grasp whose plan from START passes the envelope and the controller's limits
        (robot/pick.py) and leaves the hand room to come down, timed from the frame's read (T0), and
        what the scene's truth says of it. On one table (the camera's same_table), a part still seen
        where an earlier pick went comes after the rest: that pick failed there."""
        cell, cfg = self.cell, self.cfg
        clear = hand_clearance(frame.depth, frame.intrinsics, cell.pipeline.calib, cfg.hand) \
            if cfg.hand is not None and cell.pipeline.calib is not None else None
        record, plan, note = choose_target(seen.records, self.envelope, cfg, start, self.limits, clear, self.tried)
        t_plan = time.perf_counter()
        result = CycleResult(cycle, frame.name, len(seen.records), seen.ms, round(1000 * (t_plan - t0), 2),
                             "skipped" if record is None else "planned", note if record is None else None, frame.scene,
                             None if self.previous_frame is None else round(1000 * (t0 - self.previous_frame), 2),
                             record, plan=tuple(plan))
        self.previous_frame = t0
        if record is None:
            cell.log.write(cycle=cycle, command="none", target=None, result=f"skipped: {note}")
        return judge_cycle(result, seen.records, frame, cfg, cell.truth_cal)

    def act(self, result: CycleResult, t0: float, steps: list[StepDone], read_ahead: bool) -> CycleResult:
        """RESULT's plan carried out by the arm, when it chose something and there is an arm (STEPS gets
        each step for a recording; READ_AHEAD: the next frame may be read once the arm has left): the
        outcome, the latency of its first command and the arm's motion time."""
        robot = self.cell.robot
        if result.chosen is None or robot is None:
            return result
        motion0 = getattr(robot, "motion_s", 0.0)
        first: dict[str, float] = {}
        robot.on_send = lambda: first.setdefault("t", time.perf_counter())
        next_frame = self.ahead.start if self.ahead is not None and read_ahead else None
        on_step = _step_recorder(robot, steps) if self.cell.recorder is not None else None
        stopped = execute(list(result.plan), robot, self.cell.gripper, self.cell.log, result.cycle, self.cfg,
                          on_clear=next_frame, on_step=on_step)
        robot.on_send = None
        sent, commands_done = first.get("t"), time.perf_counter()
        verdict = result.verdict.stopped() if stopped is not None and result.verdict is not None else result.verdict
        result = replace(result, outcome="done" if stopped is None else "stopped", reason=stopped, verdict=verdict,
                         frame_to_command_ms=None if sent is None else round(1000 * (sent - t0), 2),
                         arm_wait_ms=None if sent is None or self.arm_free is None else round(1000 * (sent - self.arm_free), 2),
                         motion_s=round(getattr(robot, "motion_s", 0.0) - motion0, 3))
        self.arm_free = commands_done
        return result

    def judge(self, result: CycleResult, frame: Frame) -> tuple[CycleResult, SceneChange | None]:
        """After the commands: the physics check's verdict on a judged cycle, then a round's table
        changed by the pick (AFTER), with the round's entry of the cycle."""
        physics = self.cell.physics
        if physics is not None and result.verdict is not None:
            result = replace(result, physics=physics_verdict(result, frame, physics))
        change = self.after(result, result.chosen, frame) if self.after is not None else None
        return (result, None) if change is None else (replace(result, round=change.summary()), change)

    def report(self, result: CycleResult, frame: Frame, t0: float, seen: Perception, start: list[float] | None,
               steps: list[StepDone], change: SceneChange | None, results: list[CycleResult]) -> None:
        """The cycle's overlay, its place in RESULTS, its recording and its line, after the robot's
        commands (not part of the frame -> command latency; the recorder writes on its own thread)."""
        if self.overlay_dir:
            cv2.imwrite(str(Path(self.overlay_dir) / f"cycle_{result.cycle:03d}.png"),
                        draw_overlay(frame.rgb, [result.chosen] if result.chosen else seen.records))
        results.append(result)
        line = cycle_line(result)
        if self.cell.recorder is not None:
            frame_ns = time.time_ns() - int(1e9 * (time.perf_counter() - t0))
            self.cell.recorder.add(PickCycle(result.cycle, frame, frame_ns, seen.labels, seen.records, result.chosen,
                                             list(result.plan), start, result, steps, line, change))
        self.echo(line)


def physics_verdict(result: CycleResult, frame: Frame, physics: Callable[[Grasp, Frame, list[list[float]]], Verdict]
                    ) -> Verdict:
    """The physics check's verdict on a judged cycle: its own on a grasp that was carried out, the
    geometric one where nothing was chosen, a failure where the robot stopped."""
    if result.verdict is None:
        raise ValueError(f"cycle {result.cycle} was not judged: the physics check follows the geometric rule")
    if result.chosen is None:
        return Verdict(result.verdict.success, result.verdict.failure)
    if result.outcome == "stopped":
        return Verdict(False, "robot stopped")
    return physics(result.chosen, frame, carry_path(result.plan))


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
