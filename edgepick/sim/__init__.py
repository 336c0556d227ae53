"""Simulators used by tests and demos (a loopback UR controller)."""
