"""Simulators, for tests, the demo and benchmarks: the synthetic camera (camera.py), SimRobot
(robot.py), the grasp step on true labels (oracle.py), the physics verdict and clutter-removal
rounds (the `[sim]` extra) and a loopback UR controller for the real ur_rtde client (ur_peer.py).

    from edgepick.sim import SimRobot, SynthCamera
"""

from typing import TYPE_CHECKING

from edgepick.lazy import lazy_attributes

_WHERE = {
    "SynthCamera": "camera", "ToolMarker": "camera", "ClutterRound": "clutter", "RoundConfig": "clutter",
    "round_summary": "clutter", "run_rounds": "clutter", "TruthPipeline": "oracle", "physics_judge": "physics",
    "physics_run": "physics", "physics_verdict": "physics", "require_mujoco": "physics",
    "PhysicsConfig": "physics_scene", "SimRobot": "robot"
}
__all__ = sorted(_WHERE)

if TYPE_CHECKING:
    from edgepick.sim.camera import SynthCamera, ToolMarker
    from edgepick.sim.clutter import ClutterRound, RoundConfig, round_summary, run_rounds
    from edgepick.sim.oracle import TruthPipeline
    from edgepick.sim.physics import physics_judge, physics_run, physics_verdict, require_mujoco
    from edgepick.sim.physics_scene import PhysicsConfig
    from edgepick.sim.robot import SimRobot


__getattr__ = lazy_attributes(__name__, _WHERE)
