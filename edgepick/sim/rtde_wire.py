"""The RTDE wire format the loopback controller speaks: field types by name, and framed packages
(big-endian size, type byte, payload)."""

from __future__ import annotations

import socket
import struct
import threading

FMT = {"BOOL": "?", "UINT8": "B", "UINT32": "I", "UINT64": "Q", "INT32": "i", "DOUBLE": "d",
       "VECTOR3D": "3d", "VECTOR6D": "6d", "VECTOR6INT32": "6i", "VECTOR6UINT32": "6I"}
FIXED_TYPES = {
    "timestamp": "DOUBLE", "robot_mode": "INT32", "safety_mode": "INT32", "safety_status": "INT32",
    "runtime_state": "UINT32", "robot_status_bits": "UINT32", "safety_status_bits": "UINT32",
    "actual_digital_input_bits": "UINT64", "actual_digital_output_bits": "UINT64", "joint_mode": "VECTOR6INT32",
    "actual_tool_accelerometer": "VECTOR3D", "elbow_position": "VECTOR3D", "elbow_velocity": "VECTOR3D",
    "payload_cog": "VECTOR3D", "analog_io_types": "UINT32", "tool_mode": "UINT32", "tool_analog_input_types": "UINT32",
    "tool_output_voltage": "INT32", "output_bit_registers0_to_31": "UINT32", "output_bit_registers32_to_63": "UINT32",
    "input_bit_registers0_to_31": "UINT32", "input_bit_registers32_to_63": "UINT32", "speed_slider_mask": "UINT32",
    "script_control_line": "UINT32", "euromap67_input_bits": "UINT32", "euromap67_output_bits": "UINT32",
    "standard_digital_output_mask": "UINT8", "standard_digital_output": "UINT8",
    "configurable_digital_output_mask": "UINT8", "configurable_digital_output": "UINT8",
    "tool_digital_output_mask": "UINT8", "tool_digital_output": "UINT8", "standard_analog_output_mask": "UINT8",
    "standard_analog_output_type": "UINT8", "tool_output_mode": "UINT8", "tool_digital_output0_mode": "UINT8",
    "tool_digital_output1_mode": "UINT8", "time_scale_source": "INT32",
}
VECTOR6D = ("target_q", "target_qd", "target_qdd", "target_current", "target_moment", "actual_q", "actual_qd",
            "actual_current", "joint_control_output", "actual_TCP_pose", "actual_TCP_speed", "actual_TCP_force",
            "target_TCP_pose", "target_TCP_speed", "joint_temperatures", "actual_joint_voltage", "ft_raw_wrench",
            "external_force_torque", "payload_inertia", "actual_current_window", "target_current_window")


def rtde_type(name: str) -> str:
    if name in FIXED_TYPES:
        return FIXED_TYPES[name]
    if name in VECTOR6D:
        return "VECTOR6D"
    if "_int_register_" in name:
        return "INT32"
    if "_bit_register_" in name:
        return "BOOL"
    return "DOUBLE"  # every other scalar RTDE field is a double


def recv_exact(conn: socket.socket, n: int) -> bytes:
    buf = b""
    while len(buf) < n:
        chunk = conn.recv(n - len(buf))
        if not chunk:
            raise ConnectionError("closed")
        buf += chunk
    return buf


def send_package(conn: socket.socket, kind: bytes, payload: bytes, lock: threading.Lock) -> None:
    with lock:
        conn.sendall(struct.pack(">HB", 3 + len(payload), kind[0]) + payload)
