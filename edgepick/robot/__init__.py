"""Robot control for picking: a safety envelope checked before every command, `RobotBase` and its
two robots (SimRobot in-process, URRobot over ur_rtde), grippers, and the pick loop. No torch."""
