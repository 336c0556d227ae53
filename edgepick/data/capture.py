"""`edgepick data capture`: save RGB + depth + intrinsics from a camera for later annotation
(e.g. in CVAT), in the folder layout that `dir:PATH` cameras read back."""

from __future__ import annotations

import json
import time
from pathlib import Path

import cv2
from tqdm import tqdm

from edgepick.data.native import atomic_folder
from edgepick.errors import ConfigError, ParameterError
from edgepick.frames import Camera

MAX_FRAMES = 100_000  # about 90 GB of 640x480 PNGs


def check_count(count: int) -> None:
    """Refuse a frame count below 1 or above MAX_FRAMES."""
    if not 1 <= count <= MAX_FRAMES:
        raise ParameterError(f"{{count}}: capture 1 to {MAX_FRAMES} frames at once", count=count)


def capture(camera: Camera, out: str | Path, count: int, interval_s: float = 0.0) -> dict:
    """Write `count` frames to OUT/rgb, OUT/depth and OUT/intrinsics.json; all or nothing."""
    out = Path(out)
    check_count(count)
    with atomic_folder(out) as tmp:
        (tmp / "rgb").mkdir()
        (tmp / "depth").mkdir()
        with camera as cam:
            (tmp / "intrinsics.json").write_text(json.dumps(cam.intrinsics.to_dict(), indent=1))
            for i in tqdm(range(count), desc="capture", unit="frame", disable=None):
                if i and interval_s > 0:
                    time.sleep(interval_s)
                try:
                    frame = cam.read()
                except StopIteration:
                    raise ConfigError(f"the camera ran out of frames after {i} of {count}") from None
                ok = cv2.imwrite(str(tmp / "rgb" / f"{i:06d}.png"), frame.rgb[..., ::-1])
                ok &= cv2.imwrite(str(tmp / "depth" / f"{i:06d}.png"), frame.depth)
                if not ok:
                    raise OSError(f"could not write frame {i} under {tmp}")
            intr = cam.intrinsics
    return {"out": str(out), "frames": count, "size": [intr.width, intr.height], "depth_scale": intr.depth_scale}
