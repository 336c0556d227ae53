"""SynthCamera mounted over the cell: objects only in the pick area the arm reaches; the same frames
for the same seed."""

from __future__ import annotations

import numpy as np

from edgepick.sim.camera import SynthCamera


def test_mounted_camera_puts_objects_in_the_pick_area_and_sees_the_table_around_it():
    camera = SynthCamera(320, 240, seed=3, mount_height_m=0.7)
    cal = camera.calibration()
    (x0, x1), (y0, y1) = SynthCamera.PICK_AREA_M
    frames = [camera.read() for _ in range(12)]
    points = [cal.apply(np.asarray(t["point_camera_m"])) for f in frames for t in f.truth]
    assert len(points) >= 12
    assert all(x0 <= p[0] <= x1 and y0 <= p[1] <= y1 for p in points)  # centres in the tray (tops: same x, y)
    assert all((f.labels[:, :20] == 0).mean() > 0.9 for f in frames)  # the table beside the tray is in view
    again = SynthCamera(320, 240, seed=3, mount_height_m=0.7).read()
    assert np.array_equal(again.rgb, frames[0].rgb) and again.truth == frames[0].truth
