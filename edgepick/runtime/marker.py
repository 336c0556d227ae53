"""A fiducial marker on the robot's tool, seen by the camera: the camera half of a calibration pair.

`aruco:DICT:ID[:SIZE_MM]` names an ArUco marker (OpenCV's predefined dictionaries, e.g.
4X4_50). `detect_marker` finds it with OpenCV's ArUco detector and turns its centre into a
camera-frame 3D point: the pixel where the marker's diagonals cross, at the median depth of the
marker's own valid depth pixels (a black-and-white print is matte, so the D415 reads it well,
while its edges and the tool around it are where depth holes and mixed pixels are). With the
printed size given, a sighting whose 3D side length is off by more than 25% is refused as a
mis-detection or a bad depth.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from edgepick.errors import ParameterError
from edgepick.frames import Frame
from edgepick.geometry import deproject


@dataclass(frozen=True)
class MarkerSpec:
    dictionary: str  # OpenCV's name without DICT_, e.g. 4X4_50
    marker_id: int
    size_m: float | None = None  # printed side length of the black square, when known

    @classmethod
    def parse(cls, spec: str) -> MarkerSpec:
        """'aruco:DICT:ID[:SIZE_MM]', e.g. aruco:4X4_50:7:40."""
        parts = spec.split(":")
        if len(parts) not in (3, 4) or parts[0] != "aruco":
            raise ParameterError("{spec}: use aruco:DICT:ID[:SIZE_MM], e.g. aruco:4X4_50:7:40", spec=spec)
        name = parts[1].upper()
        if not hasattr(cv2.aruco, f"DICT_{name}"):
            known = sorted(n[5:] for n in dir(cv2.aruco) if n.startswith("DICT_") and n[5:6].isdigit())
            raise ParameterError(f"{{spec}}: unknown ArUco dictionary {parts[1]} (e.g. {', '.join(known[:6])})",
                                 spec=spec)
        try:
            marker_id = int(parts[2])
            size_m = float(parts[3]) / 1000 if len(parts) == 4 else None
        except ValueError:
            raise ParameterError("{spec}: the id and the size (mm) must be numbers", spec=spec) from None
        if not 0 <= marker_id < cls(name, 0).dictionary_size():
            raise ParameterError(f"{{spec}}: dictionary {name} has ids 0 to {cls(name, 0).dictionary_size() - 1}",
                                 spec=spec)
        if size_m is not None and not (np.isfinite(size_m) and 0.005 <= size_m <= 0.5):
            raise ParameterError("{spec}: the size is the printed side in millimetres (5 to 500)", spec=spec)
        return cls(name, marker_id, size_m)

    def dictionary_size(self) -> int:
        return int(self._dictionary().bytesList.shape[0])

    def _dictionary(self):
        return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, f"DICT_{self.dictionary}"))

    def image(self, pixels: int) -> np.ndarray:
        """The marker as a uint8 grey image, PIXELS wide, black border included (what to print)."""
        return cv2.aruco.generateImageMarker(self._dictionary(), self.marker_id, pixels)

    def detector(self):
        params = cv2.aruco.DetectorParameters()
        params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
        return cv2.aruco.ArucoDetector(self._dictionary(), params)


@dataclass
class Sighting:
    corners_px: np.ndarray  # [4, 2] in OpenCV's order (clockwise from the marker's top left)
    centre_px: tuple[float, float]
    point_camera_m: np.ndarray  # the centre, camera frame
    depth_pixels: int  # valid depth readings the depth came from


def _diagonals_cross(c: np.ndarray) -> tuple[float, float]:
    """Where the lines corner0-corner2 and corner1-corner3 meet (the centre under perspective)."""
    p, r = c[0], c[2] - c[0]
    q, s = c[1], c[3] - c[1]
    denom = r[0] * s[1] - r[1] * s[0]
    if abs(denom) < 1e-9:
        m = c.mean(0)
        return float(m[0]), float(m[1])
    t = ((q - p)[0] * s[1] - (q - p)[1] * s[0]) / denom
    x = p + t * r
    return float(x[0]), float(x[1])


def detect_marker(frame: Frame, spec: MarkerSpec, min_depth_pixels: int = 20) -> tuple[Sighting | None, str]:
    """The marker's sighting in FRAME, or None and why not (not seen, no depth, wrong size)."""
    grey = cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2GRAY)
    corners, ids, _ = spec.detector().detectMarkers(grey)
    if ids is None or spec.marker_id not in ids.ravel():
        return None, "marker not seen"
    c = np.asarray(corners[list(ids.ravel()).index(spec.marker_id)], np.float64).reshape(4, 2)
    centre = np.array(_diagonals_cross(c))
    inner = centre + 0.8 * (c - centre)  # the marker's own pixels, away from its edge
    mask = np.zeros(frame.depth.shape, np.uint8)
    cv2.fillConvexPoly(mask, np.round(inner).astype(np.int32), 1)
    values = frame.depth[(mask > 0) & (frame.depth > 0)]
    if len(values) < min_depth_pixels:
        return None, f"marker seen, but only {len(values)} of its pixels have depth"
    z = float(np.median(values)) * frame.intrinsics.depth_scale
    point = deproject(frame.intrinsics, centre[0], centre[1], z)
    if spec.size_m is not None:
        ends = [deproject(frame.intrinsics, u, v, z) for u, v in c]
        side = float(np.mean([np.linalg.norm(ends[i] - ends[(i + 1) % 4]) for i in range(4)]))
        if not 0.75 < side / spec.size_m < 1.25:
            return None, f"marker seen {side * 1000:.0f} mm wide, printed {spec.size_m * 1000:.0f} mm: a bad depth?"
    return Sighting(c, (float(centre[0]), float(centre[1])), point, int(len(values))), ""
