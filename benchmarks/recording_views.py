"""The README's pictures of a recording: a `pick --record` run in the synthetic cell, shown as Foxglove's
panels would show it (drawn here with OpenCV from the recorded messages: Foxglove is a desktop
or web app and does not run on a headless machine) and as Rerun's viewer shows it (a screenshot
from its headless mode, when rerun-sdk is installed).

    python benchmarks/recording_views.py [--cycles 4] [--cycle 3] [--out docs/images]
                                         [--recording run.mcap] [--no-rerun]

Writes OUT/recording-panels.png (colour with /camera/annotations, depth in a colour map, the
label overlay, and a 3D view of /tf, /grasp/markers, /plan/targets and the TCP path of /robot/tcp)
and, with rerun-sdk (`pip install rerun-sdk`; a headless machine also needs a Vulkan driver, e.g.
Mesa's lavapipe: `apt-get install mesa-vulkan-drivers`), OUT/recording-rerun.png.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from edgepick.robot.messages import rotation  # noqa: E402

PANEL = (640, 480)
EYE, LOOK_AT = np.array([1.05, 0.75, 0.95]), np.array([0.12, -0.12, 0.22])  # the 3D view's camera, base frame


def record(path: Path, cycles: int) -> None:
    subprocess.run([sys.executable, "-m", "edgepick", "pick", "--cycles", str(cycles), "--record", str(path),
                    "--log", str(path.with_suffix(".jsonl"))], check=True, stdout=subprocess.DEVNULL)


def messages_of_cycle(path: Path, cycle: int) -> dict:
    """The last message of each topic up to CYCLE's /pick/cycle, and every /robot/tcp of that cycle."""
    seen: dict = {"tcp": [], "tf": {}}
    with open(path, "rb") as f:
        for _, channel, _, message in make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages(
                log_time_order=True):
            seen[channel.topic] = message
            if channel.topic == "/tf":
                seen["tf"].update({tf.child_frame_id: tf for tf in message.transforms})
            if channel.topic == "/robot/gripper" and message.cycle != cycle:
                seen["tcp"] = []
            if channel.topic == "/robot/tcp":
                seen["tcp"].append(message)
            if channel.topic == "/pick/cycle" and message.cycle == cycle:
                return seen
    raise SystemExit(f"{path} has no cycle {cycle}")


def colour(c) -> tuple[int, int, int]:
    return int(255 * c.b), int(255 * c.g), int(255 * c.r)  # BGR


def image_panel(m: dict) -> np.ndarray:
    """Foxglove's Image panel: /camera/color with /camera/annotations."""
    img = cv2.imdecode(np.frombuffer(m["/camera/color"].data, np.uint8), cv2.IMREAD_COLOR)
    notes = m["/camera/annotations"]
    for c in notes.circles:
        cv2.circle(img, (round(c.position.x), round(c.position.y)), round(c.diameter / 2), colour(c.outline_color),
                   round(c.thickness), cv2.LINE_AA)
    for p in notes.points:
        pts = np.array([[q.x, q.y] for q in p.points], np.int32)
        cv2.polylines(img, [pts], False, colour(p.outline_color), round(p.thickness), cv2.LINE_AA)
    for t in notes.texts:
        cv2.putText(img, t.text, (round(t.position.x), round(t.position.y)), cv2.FONT_HERSHEY_SIMPLEX, 0.5,
                    colour(t.text_color), 1, cv2.LINE_AA)
    return img


def depth_panel(m: dict) -> np.ndarray:
    """Foxglove's Image panel on 16UC1: a colour map over the depth range, no reading black."""
    d = m["/camera/depth"]
    depth = np.frombuffer(d.data, np.uint16).reshape(d.height, d.width).astype(np.float32)
    valid = depth > 0
    lo, hi = np.percentile(depth[valid], [1, 99])
    img = cv2.applyColorMap(np.clip(255 * (depth - lo) / max(hi - lo, 1), 0, 255).astype(np.uint8), cv2.COLORMAP_TURBO)
    img[~valid] = 0
    return img


def view_3d(m: dict) -> np.ndarray:
    """Foxglove's 3D panel in the base frame: the table grid, base and camera frames, the grasp
    arrows (/grasp/markers), the plan's targets (/plan/targets) and the TCP's path (/robot/tcp)."""
    img = np.full((PANEL[1], PANEL[0], 3), 32, np.uint8)
    forward = (LOOK_AT - EYE) / np.linalg.norm(LOOK_AT - EYE)
    right = np.cross(forward, [0, 0, 1.0])
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    R = np.stack([right, down, forward])  # base -> view camera
    K = np.array([[560.0, 0, PANEL[0] / 2], [0, 560.0, PANEL[1] / 2], [0, 0, 1]])

    def px(points) -> np.ndarray:
        pts = (np.asarray(points, np.float64).reshape(-1, 3) - EYE) @ R.T
        return (pts @ K.T)[:, :2] / pts[:, 2:3]

    def line(a, b, bgr, width=1) -> None:
        (x0, y0), (x1, y1) = px([a, b])
        cv2.line(img, (round(x0), round(y0)), (round(x1), round(y1)), bgr, width, cv2.LINE_AA)

    for v in np.arange(-0.45, 0.46, 0.05):
        line([v, -0.45, 0], [v, 0.45, 0], (70, 70, 70))
        line([-0.45, v, 0], [0.45, v, 0], (70, 70, 70))
    cam = m["tf"].get("camera")
    axes = [(np.zeros(3), np.eye(3))]
    if cam is not None:
        Rc = rotation(cam.rotation)
        tc = np.array([cam.translation.x, cam.translation.y, cam.translation.z])
        axes.append((tc, Rc))
        k = m["/camera/calibration"]
        corners = [[(u - k.K[2]) / k.K[0], (v - k.K[5]) / k.K[4], 1.0] for u, v in
                   ((0, 0), (k.width, 0), (k.width, k.height), (0, k.height))]
        far = [tc + Rc @ (0.25 * np.array(c)) for c in corners]
        for i in range(4):
            line(tc, far[i], (200, 200, 200))
            line(far[i], far[(i + 1) % 4], (200, 200, 200))
    for origin, rot in axes:
        for axis, bgr in zip(rot.T, ((0, 0, 255), (0, 200, 0), (255, 80, 0)), strict=True):
            line(origin, origin + 0.08 * axis, bgr, 2)
    path = [[p.pose.position.x, p.pose.position.y, p.pose.position.z] for p in m["tcp"]]
    for a, b in zip(path, path[1:], strict=False):
        line(a, b, (0, 165, 255), 2)
    cloud = m["/plan/targets"]
    rows = np.frombuffer(cloud.data, np.uint8).reshape(-1, cloud.point_stride)
    for x, y in px(rows[:, :12].copy().view("<f4")):
        cv2.circle(img, (round(x), round(y)), 5, (255, 128, 50), -1, cv2.LINE_AA)
    for entity in m["/grasp/markers"].entities:
        for arrow in entity.arrows:
            p = np.array([arrow.pose.position.x, arrow.pose.position.y, arrow.pose.position.z])
            tool_x = rotation(arrow.pose.orientation)[:, 0]
            line(p - 0.03 * tool_x, p + 0.03 * tool_x, colour(arrow.color), 3)
        for text in entity.texts:
            (x, y), = px([[text.pose.position.x, text.pose.position.y, text.pose.position.z]])
            cv2.putText(img, text.text, (round(x) + 6, round(y)), cv2.FONT_HERSHEY_SIMPLEX, 0.45, colour(text.color), 1,
                        cv2.LINE_AA)
    cv2.putText(img, "3D (base frame): camera, grasps, plan targets, TCP path", (10, 20), cv2.FONT_HERSHEY_SIMPLEX,
                0.5, (220, 220, 220), 1, cv2.LINE_AA)
    return img


def panels(path: Path, cycle: int, out: Path) -> None:
    m = messages_of_cycle(path, cycle)
    overlay = cv2.imdecode(np.frombuffer(m["/segmentation/overlay"].data, np.uint8), cv2.IMREAD_COLOR)
    tiles = [("/camera/color + /camera/annotations", image_panel(m)), ("/camera/depth", depth_panel(m)),
             ("/segmentation/overlay", overlay), ("/tf, /grasp/markers, /plan/targets, /robot/tcp", view_3d(m))]
    framed = []
    for title, tile in tiles:
        tile = cv2.resize(tile, PANEL)
        bar = np.full((28, PANEL[0], 3), 20, np.uint8)
        cv2.putText(bar, title, (8, 19), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (235, 235, 235), 1, cv2.LINE_AA)
        framed.append(cv2.copyMakeBorder(np.vstack([bar, tile]), 2, 2, 2, 2, cv2.BORDER_CONSTANT, value=(60, 60, 60)))
    c = m["/pick/cycle"]
    footer = np.full((34, 2 * framed[0].shape[1], 3), 20, np.uint8)
    verdict = "success" if c.success else f"failed ({c.failure})"
    cv2.putText(footer, f"/pick/cycle {c.cycle}: {c.target} at ({c.pixel[0]:.0f}, {c.pixel[1]:.0f}), inference "
                f"{c.inference_ms:.0f} ms, grasp {c.grasp_ms:.1f} ms, frame -> first command {c.frame_to_command_ms:.0f} "
                f"ms, verdict {verdict}", (8, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (235, 235, 235), 1, cv2.LINE_AA)
    picture = np.vstack([np.hstack(framed[:2]), np.hstack(framed[2:]), footer])
    cv2.imwrite(str(out), cv2.resize(picture, None, fx=0.75, fy=0.75, interpolation=cv2.INTER_AREA),
                [cv2.IMWRITE_PNG_COMPRESSION, 9])
    print(f"written to {out}", file=sys.stderr)


def rerun_screenshot(path: Path, out: Path, cycle_time_s: float) -> None:
    """Rerun's viewer, headless, on the recording at the given cycle's time; its screenshot."""
    try:
        import rerun.experimental as rre
    except ModuleNotFoundError:
        print("rerun-sdk is not installed: no Rerun screenshot (pip install rerun-sdk)", file=sys.stderr)
        return
    viewer = rre.ViewerClient.spawn(headless=True, hide_welcome_screen=True)
    try:
        viewer.open(str(path))
        time.sleep(6)  # loading, and the viewer's start-up notices fading
        viewer.set_time("timestamp", timestamp=cycle_time_s, play_state="paused")
        time.sleep(3)
        viewer.save_screenshot(str(out))
        print(f"written to {out}", file=sys.stderr)
    finally:
        viewer.quit()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--recording", default=None, help="a `pick --record` file [default: record --cycles new ones]")
    ap.add_argument("--cycles", type=int, default=4)
    ap.add_argument("--cycle", type=int, default=3, help="the cycle to show")
    ap.add_argument("--out", default=str(Path(__file__).resolve().parents[1] / "docs" / "images"))
    ap.add_argument("--no-rerun", action="store_true", help="skip Rerun's screenshot")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(args.recording) if args.recording else Path(tmp) / "run.mcap"
        if not args.recording:
            record(path, args.cycles)
        panels(path, args.cycle, out / "recording-panels.png")
        if not args.no_rerun:
            stamp = messages_of_cycle(path, args.cycle)["/pick/cycle"].frame_time.ToNanoseconds()
            rerun_screenshot(path, out / "recording-rerun.png", stamp / 1e9 + 0.05)  # just after: float seconds round


if __name__ == "__main__":
    main()
