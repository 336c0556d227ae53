"""A loopback UR controller for tests: RTDE (30004), dashboard (29999) and script (30003) on a
127.0.0.N address, enough for the real ur_rtde client (RTDEControl/Receive/IOInterface).

It carries out the register protocol of ur_rtde's control script (moveJ, moveL, stopL, the
safety-limit query, stop script), the IO interface's digital outputs, and moves a UR3 TCP at
the commanded speed. It can raise a protective stop or drop every link halfway through the
N-th motion. Every command it receives is appended to a JSON-lines log. Run it as its own
process (ur_rtde's constructors hold the GIL):

    python -m edgepick.sim.ur_peer --host 127.0.0.5 --lifetime 60 [--protective-stop-on-move 2]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import socket
import struct
import sys
import threading
import time

VERSION = (3, 15, 7, 106331)  # a CB3 controller (UR3): 125 Hz RTDE, no remote-control check
FREQUENCY_HZ = 125.0
RUNTIME_STOPPED, RUNTIME_PLAYING = 1, 2
SAFETY_NORMAL, SAFETY_PROTECTIVE = 1, 3
PROTECTIVE_BIT, EMERGENCY_BIT = 1 << 2, 1 << 7
PROGRAM_RUNNING_BIT = 1 << 1
CMD_NONE, CMD_MOVEJ, CMD_MOVEL, CMD_STOPL, CMD_POSE_OK, CMD_STOP_SCRIPT = 0, 1, 3, 33, 36, 255
READY, DONE = 1, 2
# UR3 DH parameters (Universal Robots' published values)
DH_D = (0.1519, 0.0, 0.0, 0.11235, 0.08535, 0.0819)
DH_A = (0.0, -0.24365, -0.21325, 0.0, 0.0, 0.0)
DH_ALPHA = (math.pi / 2, 0.0, 0.0, math.pi / 2, -math.pi / 2, 0.0)
REACH_M = 0.5

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


def forward_kinematics(q: list[float]) -> list[float]:
    """UR3 TCP pose [x, y, z, rx, ry, rz] of joint angles (standard DH)."""
    T = [[1.0 if i == j else 0.0 for j in range(4)] for i in range(4)]
    for th, d, a, al in zip(q, DH_D, DH_A, DH_ALPHA):
        ct, st, ca, sa = math.cos(th), math.sin(th), math.cos(al), math.sin(al)
        A = [[ct, -st * ca, st * sa, a * ct], [st, ct * ca, -ct * sa, a * st], [0, sa, ca, d], [0, 0, 0, 1]]
        T = [[sum(T[i][k] * A[k][j] for k in range(4)) for j in range(4)] for i in range(4)]
    return [T[0][3], T[1][3], T[2][3], *rotvec(T)]


def rotvec(T) -> list[float]:
    c = max(-1.0, min(1.0, (T[0][0] + T[1][1] + T[2][2] - 1) / 2))
    angle = math.acos(c)
    if angle < 1e-9:
        return [0.0, 0.0, 0.0]
    if math.pi - angle < 1e-6:  # half turn: axis from the diagonal
        axis = [math.sqrt(max(0.0, (T[i][i] + 1) / 2)) for i in range(3)]
        if T[0][1] < 0:
            axis[1] = -axis[1]
        if T[0][2] < 0:
            axis[2] = -axis[2]
        return [angle * a for a in axis]
    s = 2 * math.sin(angle)
    return [angle * (T[2][1] - T[1][2]) / s, angle * (T[0][2] - T[2][0]) / s, angle * (T[1][0] - T[0][1]) / s]


def reachable(pose: list[float]) -> bool:
    x, y, z = pose[:3]
    return math.sqrt(x * x + y * y + (z - DH_D[0]) ** 2) <= REACH_M


START_JOINTS = [math.pi, -math.pi / 2, math.pi / 2, -math.pi / 2, -math.pi / 2, 0.0]


class Controller:
    """The simulated controller state, shared by all connections (one lock)."""

    def __init__(self, args: argparse.Namespace):
        self.args = args
        self.lock = threading.RLock()
        self.q = list(args.start_joints)
        self.tcp = forward_kinematics(self.q)
        self.motion: dict | None = None
        self.runtime = RUNTIME_STOPPED
        self.safety_mode = SAFETY_NORMAL
        self.safety_bits = 1  # normal mode
        self.out_int = [0] * 48
        self.out_double = [0.0] * 48
        self.digital_out = 0
        self.moves = 0
        self.last_cmd = None
        self.dropped = threading.Event()
        self.log = open(args.log, "a") if args.log else None
        self.t0 = time.monotonic()

    def record(self, **entry) -> None:
        if self.log:
            self.log.write(json.dumps({"t": round(time.monotonic() - self.t0, 4), **entry}) + "\n")
            self.log.flush()

    # -- state the client reads ------------------------------------------------------------------
    def value(self, name: str):
        self.tick()
        if name in ("actual_TCP_pose", "target_TCP_pose"):
            return self.tcp
        if name in ("actual_q", "target_q"):
            return self.q
        if name == "runtime_state":
            return self.runtime
        if name == "robot_mode":
            return 7  # running
        if name == "safety_mode" or name == "safety_status":
            return self.safety_mode
        if name == "safety_status_bits":
            return self.safety_bits
        if name == "robot_status_bits":
            return 1 | (PROGRAM_RUNNING_BIT if self.runtime == RUNTIME_PLAYING else 0)
        if name == "actual_digital_output_bits":
            return self.digital_out
        if name == "timestamp":
            return time.monotonic() - self.t0
        if name.startswith("output_int_register_"):
            return self.out_int[int(name.rsplit("_", 1)[1])]
        if name.startswith("output_double_register_"):
            return self.out_double[int(name.rsplit("_", 1)[1])]
        if name in ("speed_scaling", "target_speed_fraction"):
            return 1.0
        kind = rtde_type(name)
        count = int(FMT[kind][0]) if FMT[kind][0].isdigit() else 1
        zero = 0.0 if FMT[kind][-1] == "d" else 0
        return [zero] * count if count > 1 else zero

    def tick(self) -> None:
        """Advance a running motion; complete it, or fire the configured fault halfway."""
        with self.lock:
            m = self.motion
            if m is None:
                return
            f = min(1.0, (time.monotonic() - m["t0"]) / m["duration"]) if m["duration"] > 0 else 1.0
            if m["fault"] and f >= 0.5:
                f = 0.5
            start, end = m["start"], m["end"]
            if m["kind"] == "joint":
                self.q = [a + f * (b - a) for a, b in zip(start, end)]
                self.tcp = forward_kinematics(self.q)
            else:
                self.tcp = [a + f * (b - a) for a, b in zip(start[:3], end[:3])] + list(end[3:])
            if m["fault"] == "protective" and f >= 0.5:
                self.motion = None
                self.safety_mode, self.safety_bits = SAFETY_PROTECTIVE, PROTECTIVE_BIT
                self.record(event="protective_stop", tcp=self.tcp)
            elif m["fault"] == "drop" and f >= 0.5:
                self.motion = None
                self.record(event="link_dropped", tcp=self.tcp)
                self.dropped.set()
            elif f >= 1.0:
                self.motion = None
                self.out_int[0] = DONE

    # -- commands the client writes ----------------------------------------------------------------
    def script_uploaded(self, text: str) -> None:
        with self.lock:
            self.record(event="script", bytes=len(text))
            if "def " in text and self.safety_mode == SAFETY_NORMAL:
                self.runtime = RUNTIME_PLAYING
                self.out_int[0] = READY

    def inputs(self, values: dict) -> None:
        with self.lock:
            self.tick()
            if "standard_digital_output_mask" in values or "tool_digital_output_mask" in values:
                self._outputs(values)
            if "input_int_register_0" not in values:
                return
            cmd = values["input_int_register_0"]
            if cmd == CMD_NONE:
                if self.out_int[0] == DONE:
                    self.out_int[0] = READY
                return
            if self.runtime != RUNTIME_PLAYING or self.out_int[0] != READY:
                return  # the script is not running, or is busy with the previous command
            d = [values.get(f"input_double_register_{i}", 0.0) for i in range(8)]
            self.record(cmd=cmd, values=[round(v, 6) for v in d])
            self.out_int[0] = 0
            if self.safety_mode != SAFETY_NORMAL:
                return  # a stopped robot does nothing
            if cmd in (CMD_MOVEL, CMD_MOVEJ):
                self._start_motion(cmd, d)
            elif cmd == CMD_STOPL:
                self.motion = None
                self.out_int[0] = DONE
            elif cmd == CMD_POSE_OK:
                self.out_int[1] = int(reachable(d[:6]))
                self.out_int[0] = DONE
            elif cmd == CMD_STOP_SCRIPT:
                self.motion = None
                self.runtime = RUNTIME_STOPPED
            else:
                self.out_int[0] = DONE

    def _start_motion(self, cmd: int, d: list[float]) -> None:
        target, speed, acc = d[:6], max(d[6], 1e-6), max(d[7], 1e-6)
        if cmd == CMD_MOVEL:
            if not reachable(target):  # the real controller stops the program on an IK failure
                self.runtime = RUNTIME_STOPPED
                self.record(event="ik_failure", target=target)
                return
            dist, start, kind = math.dist(self.tcp[:3], target[:3]), list(self.tcp), "linear"
        else:
            dist, start, kind = max(abs(a - b) for a, b in zip(self.q, target)), list(self.q), "joint"
        ramp = speed * speed / acc
        duration = 2 * math.sqrt(dist / acc) if dist < ramp else dist / speed + speed / acc
        self.moves += 1
        fault = "protective" if self.moves == self.args.protective_stop_on_move else \
            "drop" if self.moves == self.args.drop_on_move else None
        self.motion = {"kind": kind, "start": start, "end": target, "t0": time.monotonic(),
                       "duration": duration * self.args.time_scale, "fault": fault}

    def _outputs(self, v: dict) -> None:
        std_mask, std = v.get("standard_digital_output_mask", 0), v.get("standard_digital_output", 0)
        tool_mask, tool = v.get("tool_digital_output_mask", 0), v.get("tool_digital_output", 0)
        bits = self.digital_out
        bits = (bits & ~std_mask) | (std & std_mask)
        bits = (bits & ~(tool_mask << 16)) | ((tool & tool_mask) << 16)
        if bits != self.digital_out:
            self.record(event="digital_out", bits=bits)
        self.digital_out = bits


# ----------------------------------------------------------------------------------- sockets
def _recv_exact(conn: socket.socket, n: int) -> bytes:
    buf = b""
    while len(buf) < n:
        chunk = conn.recv(n - len(buf))
        if not chunk:
            raise ConnectionError("closed")
        buf += chunk
    return buf


def _send(conn: socket.socket, kind: bytes, payload: bytes, lock: threading.Lock) -> None:
    with lock:
        conn.sendall(struct.pack(">HB", 3 + len(payload), kind[0]) + payload)


def serve_rtde(ctl: Controller, conn: socket.socket) -> None:
    """One RTDE client: recipes, start, a 125 Hz output stream, input packages."""
    lock = threading.Lock()
    inputs: dict[int, list[tuple[str, str]]] = {}
    output: list[tuple[str, str]] = []
    streaming = threading.Event()

    def stream() -> None:
        period = 1.0 / FREQUENCY_HZ
        nxt = time.monotonic()
        while not ctl.dropped.is_set():
            with ctl.lock:
                parts = []
                for name, kind in output:
                    v = ctl.value(name)
                    parts.append(struct.pack(">" + FMT[kind], *(v if isinstance(v, (list, tuple)) else [v])))
            try:
                _send(conn, b"U", bytes([1]) + b"".join(parts), lock)
            except OSError:
                return
            nxt += period
            time.sleep(max(0.0, nxt - time.monotonic()))

    try:
        while not ctl.dropped.is_set():
            size, kind = struct.unpack(">HB", _recv_exact(conn, 3))
            body = _recv_exact(conn, size - 3)
            k = chr(kind)
            if k == "V":
                _send(conn, b"V", b"\x01", lock)
            elif k == "v":
                _send(conn, b"v", struct.pack(">IIII", *VERSION), lock)
            elif k == "O":
                names = [n for n in body[8:].decode().split(",") if n]
                output = [(n, rtde_type(n)) for n in names]
                ctl.record(event="output_recipe", names=names)
                _send(conn, b"O", bytes([1]) + ",".join(t for _, t in output).encode(), lock)
            elif k == "I":
                names = [n for n in body.decode().split(",") if n]
                rid = len(inputs) + 1
                inputs[rid] = [(n, rtde_type(n)) for n in names]
                _send(conn, b"I", bytes([rid]) + ",".join(t for _, t in inputs[rid]).encode(), lock)
            elif k == "S":
                _send(conn, b"S", b"\x01", lock)
                if output and not streaming.is_set():
                    streaming.set()
                    threading.Thread(target=stream, daemon=True).start()
            elif k == "P":
                _send(conn, b"P", b"\x01", lock)
            elif k == "U":
                recipe = inputs.get(body[0], [])
                values, offset = {}, 1
                for name, t in recipe:
                    fmt = ">" + FMT[t]
                    vals = struct.unpack_from(fmt, body, offset)
                    offset += struct.calcsize(fmt)
                    values[name] = vals[0] if len(vals) == 1 else list(vals)
                ctl.inputs(values)
    except (ConnectionError, OSError, struct.error):
        pass
    finally:
        conn.close()


def serve_dashboard(ctl: Controller, conn: socket.socket) -> None:
    answers = {"PolyscopeVersion": "URSoftware 3.15.7.106331 (Mar 02 2023)", "get serial number": "2017300000",
               "is in remote control": "true", "stop": "Stopped", "robotmode": "Robotmode: RUNNING",
               "unlock protective stop": "Protective stop releasing", "close popup": "closing popup",
               "quit": "Disconnected"}
    try:
        conn.sendall(b"Connected: Universal Robots Dashboard Server\n")
        buf = b""
        while not ctl.dropped.is_set():
            chunk = conn.recv(1024)
            if not chunk:
                return
            buf += chunk
            while b"\n" in buf:
                line, buf = buf.split(b"\n", 1)
                text = line.decode(errors="replace").strip()
                ctl.record(dashboard=text)
                if text == "unlock protective stop":
                    with ctl.lock:
                        ctl.safety_mode, ctl.safety_bits = SAFETY_NORMAL, 1
                conn.sendall((answers.get(text, f"could not understand: '{text}'") + "\n").encode())
    except OSError:
        pass
    finally:
        conn.close()


def serve_script(ctl: Controller, conn: socket.socket) -> None:
    """Scripts arrive as text; a complete `def ...: ... end` program starts running."""
    buf = ""
    try:
        conn.settimeout(0.2)
        while not ctl.dropped.is_set():
            try:
                chunk = conn.recv(65536)
            except socket.timeout:
                if buf:
                    ctl.script_uploaded(buf)
                    buf = ""
                continue
            if not chunk:
                break
            buf += chunk.decode(errors="replace")
        if buf:
            ctl.script_uploaded(buf)
    except OSError:
        pass
    finally:
        conn.close()


def listen(ctl: Controller, host: str, port: int, handler, conns: list) -> socket.socket:
    srv = socket.socket()
    srv.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    srv.bind((host, port))
    srv.listen(8)

    def accept() -> None:
        while not ctl.dropped.is_set():
            try:
                conn, _ = srv.accept()
            except OSError:
                return
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            conns.append(conn)
            threading.Thread(target=handler, args=(ctl, conn), daemon=True).start()

    threading.Thread(target=accept, daemon=True).start()
    return srv


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--host", default="127.0.0.2", help="a loopback address, 127.0.0.N")
    ap.add_argument("--lifetime", type=float, default=60.0, help="seconds before the peer exits on its own")
    ap.add_argument("--protective-stop-on-move", type=int, default=0, help="raise a protective stop halfway through move N")
    ap.add_argument("--drop-on-move", type=int, default=0, help="close every link halfway through move N")
    ap.add_argument("--time-scale", type=float, default=1.0, help="motion time factor (0.1 = ten times faster)")
    ap.add_argument("--log", default=None, help="JSON-lines log of every command received")
    ap.add_argument("--start-joints", type=float, nargs=6, default=START_JOINTS, metavar="Q",
                    help="joint angles (rad) at start [default: the TCP above the +x side of the base, where "
                         "edgepick's home and the synthetic cell are]")
    args = ap.parse_args(argv)
    if not args.host.startswith("127."):
        ap.error("the peer only listens on loopback addresses (127.0.0.N)")
    ctl = Controller(args)
    conns: list[socket.socket] = []
    servers = [listen(ctl, args.host, port, handler, conns)
               for port, handler in ((30004, serve_rtde), (29999, serve_dashboard), (30003, serve_script))]
    print(f"ur_peer ready on {args.host} (pid {os.getpid()})", flush=True)
    deadline = time.monotonic() + args.lifetime
    while time.monotonic() < deadline and not ctl.dropped.is_set():
        ctl.tick()
        time.sleep(0.005)
    for s in servers + conns:  # drop every link at once, like a controller that disappears
        try:
            s.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        s.close()
    if ctl.dropped.is_set():
        time.sleep(min(2.0, max(0.0, deadline - time.monotonic())))  # stay silent, then exit
    sys.exit(0)


if __name__ == "__main__":
    main()
