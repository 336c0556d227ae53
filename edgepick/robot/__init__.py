"""Robot control for picking: a safety envelope checked before every command, `RobotBase` and its
two robots (SimRobot in-process, URRobot over ur_rtde), grippers, and the pick loop. No torch.

    from edgepick.robot import Envelope, PickConfig, choose_target, plan_pick
"""

from typing import TYPE_CHECKING

from edgepick.lazy import lazy_attributes

_WHERE = {
    "RobotBase": "base", "RobotError": "base", "RobotHalted": "base", "RobotUnreachable": "base",
    "SafetyStatus": "base", "HandShape": "clearance", "hand_clearance": "clearance", "Envelope": "envelope",
    "SafetyError": "envelope", "DigitalGripper": "grippers", "GripperFailed": "grippers", "RG2Gripper": "grippers",
    "CycleResult": "cycle", "CollectConfig": "handeye", "collect_pairs": "handeye", "plan_positions": "handeye",
    "Cell": "loop", "Lookahead": "loop", "cycles_summary": "loop", "run_cycles": "loop", "HOME_POSE": "motion",
    "motion_time": "motion", "Choose": "pick", "CommandLog": "pick", "PickConfig": "pick", "Step": "pick",
    "choose_target": "pick", "execute": "pick", "plan_pick": "pick", "Recorder": "recording",
    "pick_metadata": "recording", "RecordingError": "replay", "open_recording": "replay", "URRobot": "ur",
    "Verdict": "verdict", "VerdictRule": "verdict", "judge": "verdict", "summarize": "verdict"
}
__all__ = sorted(_WHERE)

if TYPE_CHECKING:
    from edgepick.robot.base import RobotBase, RobotError, RobotHalted, RobotUnreachable, SafetyStatus
    from edgepick.robot.clearance import HandShape, hand_clearance
    from edgepick.robot.cycle import CycleResult
    from edgepick.robot.envelope import Envelope, SafetyError
    from edgepick.robot.grippers import DigitalGripper, GripperFailed, RG2Gripper
    from edgepick.robot.handeye import CollectConfig, collect_pairs, plan_positions
    from edgepick.robot.loop import Cell, Lookahead, cycles_summary, run_cycles
    from edgepick.robot.motion import HOME_POSE, motion_time
    from edgepick.robot.pick import Choose, CommandLog, PickConfig, Step, choose_target, execute, plan_pick
    from edgepick.robot.recording import Recorder, pick_metadata
    from edgepick.robot.replay import RecordingError, open_recording
    from edgepick.robot.ur import URRobot
    from edgepick.robot.verdict import Verdict, VerdictRule, judge, summarize


__getattr__ = lazy_attributes(__name__, _WHERE)
