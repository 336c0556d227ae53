"""Simulators, for tests, the demo and benchmarks: the synthetic camera (camera.py), SimRobot
(robot.py) and a loopback UR controller for the real ur_rtde client (ur_peer.py)."""
