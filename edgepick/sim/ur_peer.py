"""A loopback UR controller for tests: RTDE (30004), dashboard (29999) and script (30003) on a
127.0.0.N address, enough for the real ur_rtde client (RTDEControl/Receive/IOInterface).

It carries out the register protocol of ur_rtde's control script (moveJ, moveL, stopL, the
safety-limit query, stop script), the IO interface's digital outputs, and moves a UR3 TCP at
the commanded speed. It can raise a protective stop or drop every link halfway through the
N-th motion, and answer the safety-limit query (isPoseWithinSafetyLimits) with "no" for poses
beyond a given x. Every command it receives is appended to a JSON-lines log. Run it as its own
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

from edgepick.sim.rtde_wire import FMT, recv_exact, rtde_type, send_package
from edgepick.sim.ur3_kinematics import forward_kinematics, reachable

VERSION = (3, 15, 7, 106331)  # a CB3 controller (UR3): 125 Hz RTDE, no remote-control check
FREQUENCY_HZ = 125.0
RUNTIME_STOPPED, RUNTIME_PLAYING = 1, 2
SAFETY_NORMAL, SAFETY_PROTECTIVE = 1, 3
PROTECTIVE_BIT, EMERGENCY_BIT = 1 << 2, 1 << 7
PROGRAM_RUNNING_BIT = 1 << 1
CMD_NONE, CMD_MOVEJ, CMD_MOVEL, CMD_STOPL, CMD_POSE_OK, CMD_STOP_SCRIPT = 0, 1, 3, 33, 36, 255
READY, DONE = 1, 2
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
                self.out_int[1] = int(self.within_limits(d[:6]))
                self.out_int[0] = DONE
            elif cmd == CMD_STOP_SCRIPT:
                self.motion = None
                self.runtime = RUNTIME_STOPPED
            else:
                self.out_int[0] = DONE

    def within_limits(self, pose: list[float]) -> bool:
        """The answer to the safety-limit query: within the UR3's reach, and not beyond --refuse-poses-beyond-x."""
        beyond = self.args.refuse_poses_beyond_x
        return reachable(pose) and (beyond is None or pose[0] <= beyond)

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
                send_package(conn, b"U", bytes([1]) + b"".join(parts), lock)
            except OSError:
                return
            nxt += period
            time.sleep(max(0.0, nxt - time.monotonic()))

    try:
        while not ctl.dropped.is_set():
            size, kind = struct.unpack(">HB", recv_exact(conn, 3))
            body = recv_exact(conn, size - 3)
            k = chr(kind)
            if k == "V":
                send_package(conn, b"V", b"\x01", lock)
            elif k == "v":
                send_package(conn, b"v", struct.pack(">IIII", *VERSION), lock)
            elif k == "O":
                names = [n for n in body[8:].decode().split(",") if n]
                output = [(n, rtde_type(n)) for n in names]
                ctl.record(event="output_recipe", names=names)
                send_package(conn, b"O", bytes([1]) + ",".join(t for _, t in output).encode(), lock)
            elif k == "I":
                names = [n for n in body.decode().split(",") if n]
                rid = len(inputs) + 1
                inputs[rid] = [(n, rtde_type(n)) for n in names]
                send_package(conn, b"I", bytes([rid]) + ",".join(t for _, t in inputs[rid]).encode(), lock)
            elif k == "S":
                send_package(conn, b"S", b"\x01", lock)
                if output and not streaming.is_set():
                    streaming.set()
                    threading.Thread(target=stream, daemon=True).start()
            elif k == "P":
                send_package(conn, b"P", b"\x01", lock)
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
            except TimeoutError:
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
    ap.add_argument("--refuse-poses-beyond-x", type=float, default=None, metavar="X",
                    help="answer the safety-limit query with 'outside' for a pose whose x is above X (metres)")
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
