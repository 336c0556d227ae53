"""Camera-to-robot calibration (docs/contracts.md#intrinsics-and-calibration): a Kabsch rigid fit,
robot = R @ camera + t.

numpy only. Degenerate inputs (fewer than 4 pairs, coincident or collinear points, NaN)
are refused with one clear sentence, since a fit through them would be silently wrong.
"""

from __future__ import annotations

import csv
import io
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from edgepick.errors import EdgepickError, ParameterError
from edgepick.files import atomic_write
from edgepick.schema import Where, as_dict, as_list, as_number, as_numbers, field, read_json, read_text

HEADER = ["cam_x", "cam_y", "cam_z", "robot_x", "robot_y", "robot_z"]
MIN_PAIRS = 4


class CalibrationError(EdgepickError):
    """Calibration pairs or a calibration file that cannot give a valid rigid transform."""


class PoorFitError(CalibrationError, ParameterError):
    """A fit too poor to be a measurement; the message names the bound's parameter (max_rmse_m)."""


@dataclass
class Calibration:
    R: np.ndarray  # 3x3 proper rotation
    t: np.ndarray  # 3
    rmse_m: float
    n_pairs: int

    def apply(self, camera_points: np.ndarray) -> np.ndarray:
        """Camera-frame point(s) [..., 3] -> robot base frame."""
        return np.asarray(camera_points) @ self.R.T + self.t

    def to_dict(self) -> dict:
        return {"R": self.R.tolist(), "t": self.t.tolist(), "rmse_m": self.rmse_m, "n_pairs": self.n_pairs}

    def save(self, path: str | Path) -> None:
        atomic_write(path, json.dumps(self.to_dict(), indent=1))

    @classmethod
    def load(cls, path: str | Path) -> Calibration:
        """Read a calib.json, every field checked: a malformed file is one line naming the file and
        the field, never a transform taken as if fine."""
        where = Where(str(path))
        d = as_dict(read_json(path, "calibration"), where)
        rows = as_list(field(d, "R", where), where.at("R"), length=3)
        R = np.array([as_numbers(row, where.at("R").at(i), 3) for i, row in enumerate(rows)], np.float64)
        t = np.array(as_numbers(field(d, "t", where), where.at("t"), 3), np.float64)
        rmse = float(as_number(d["rmse_m"], where.at("rmse_m"), minimum=0)) if "rmse_m" in d else float("nan")
        n_pairs = int(as_number(d["n_pairs"], where.at("n_pairs"), integer=True, minimum=0)) if "n_pairs" in d else 0
        if np.abs(R @ R.T - np.eye(3)).max() > 1e-4 or abs(np.linalg.det(R) - 1) > 1e-4:
            raise CalibrationError(f"calibration {path}: R is not a proper rotation (R R^T != I or det != +1)")
        if np.linalg.norm(t) > MAX_COORD_M:  # t is where the camera stands in the robot's frame
            where.at("t").fail(f"puts the camera {np.linalg.norm(t):.4g} m from the robot's base, beyond the "
                               f"{MAX_COORD_M:g} m of a picking cell; t is in metres (millimetres given?)")
        return cls(R, t, rmse, n_pairs)


MAX_COORD_M = 10.0  # no camera point or arm position of a picking cell is this far away
MAX_RMSE_M = 0.02  # a fit worse than this is a mistake in the pairs, not a measurement


def read_pairs(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """pairs.csv -> (camera points [N, 3], robot points [N, 3]), in metres. Any content that is not
    that (binary, another encoding, a broken CSV, a row of the wrong length) is one line naming the
    file and the line."""
    text = read_text(path, "pairs file")
    try:
        rows = list(csv.reader(io.StringIO(text, newline="")))
    except csv.Error as exc:
        raise CalibrationError(f"pairs file {path} is not a CSV file: {exc}") from None
    if not rows or [c.strip().lower() for c in rows[0]] != HEADER:
        raise CalibrationError(f"pairs file {path} must start with the header {','.join(HEADER)}")
    values = []
    for i, row in enumerate(rows[1:], start=2):
        if not any(c.strip() for c in row):
            continue
        if len(row) != 6:
            raise CalibrationError(f"pairs file {path} line {i}: expected 6 values, got {len(row)}")
        try:
            vals = [float(c) for c in row]
        except ValueError:
            raise CalibrationError(f"pairs file {path} line {i}: not six numbers") from None
        if not all(math.isfinite(v) for v in vals):
            raise CalibrationError(f"pairs file {path} line {i}: NaN or infinite value")
        if max(abs(v) for v in vals) > MAX_COORD_M:
            raise CalibrationError(f"pairs file {path} line {i}: a coordinate beyond {MAX_COORD_M:.0f} m; pairs are "
                                   "in metres (millimetres given?)")
        values.append(vals)
    arr = np.array(values, dtype=np.float64).reshape(-1, 6)
    return arr[:, :3], arr[:, 3:]


def _check_spread(points: np.ndarray, name: str) -> None:
    rounded = np.round(points, 6) + 0.0  # + 0.0: -0.0 and 0.0 are one position
    if len(np.unique(rounded, axis=0)) < len(points):
        raise CalibrationError(f"two {name} points coincide; every pair must be a distinct position")
    s = np.linalg.svd(points - points.mean(0), compute_uv=False)
    if s[0] < 1e-6 or s[1] / s[0] < 1e-3:
        raise CalibrationError(f"the {name} points are collinear; spread them over the workspace")


def kabsch(camera: np.ndarray, robot: np.ndarray) -> Calibration:
    """Least-squares rigid transform (rotation with det = +1, translation) from camera to robot points."""
    camera, robot = np.asarray(camera, np.float64), np.asarray(robot, np.float64)
    if camera.shape != robot.shape or camera.ndim != 2 or camera.shape[1] != 3:
        raise CalibrationError("camera and robot points must be two [N, 3] arrays of the same length")
    if len(camera) < MIN_PAIRS:
        raise CalibrationError(f"need at least {MIN_PAIRS} point pairs, got {len(camera)}")
    if not (np.isfinite(camera).all() and np.isfinite(robot).all()):
        raise CalibrationError("point pairs contain NaN or infinite values")
    _check_spread(camera, "camera")
    _check_spread(robot, "robot")
    cc, cr = camera.mean(0), robot.mean(0)
    H = (camera - cc).T @ (robot - cr)
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0
    R = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
    cal = Calibration(R, cr - R @ cc, 0.0, len(camera))
    cal.rmse_m = float(np.sqrt(np.mean(residuals(cal, camera, robot) ** 2)))
    return cal


def diagnose(cal: Calibration, camera: np.ndarray, robot: np.ndarray, max_rmse_m: float) -> None:
    """Refuse a fit whose RMSE is beyond what a camera and an arm can measure, saying what is
    likely wrong: the two sides in different units, a mirrored frame (an axis with the wrong
    sign, or two columns swapped), or pairs that are not the same physical points."""
    if cal.rmse_m <= max_rmse_m:
        return
    camera, robot = np.asarray(camera, np.float64), np.asarray(robot, np.float64)
    errors = residuals(cal, camera, robot)
    worst = int(np.argmax(errors))
    head = f"the fit's RMSE is {cal.rmse_m * 1000:.1f} mm (bound {max_rmse_m * 1000:.0f} mm, {{max_rmse_m:name}}; " \
           f"worst: pair {worst + 1}, {errors[worst] * 1000:.0f} mm)"
    spread_c = np.linalg.norm(camera - camera.mean(0), axis=1).mean()
    spread_r = np.linalg.norm(robot - robot.mean(0), axis=1).mean()
    scale = spread_r / spread_c if spread_c > 0 else float("inf")
    if not 0.5 < scale < 2:
        raise PoorFitError(f"{head}: the robot points spread {scale:.3g}x as far as the camera points; are both "
                           "sides in metres?", max_rmse_m=max_rmse_m)
    cc, cr = camera.mean(0), robot.mean(0)
    U, _, Vt = np.linalg.svd((camera - cc).T @ (robot - cr))
    d = np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0
    mirror = Vt.T @ np.diag([1.0, 1.0, -d]) @ U.T  # the best fit of the other handedness than kabsch's
    mirrored = np.sqrt(np.mean(np.linalg.norm((camera - cc) @ mirror.T - (robot - cr), axis=1) ** 2))
    if mirrored < cal.rmse_m / 3:
        raise PoorFitError(f"{head}; a mirror image of the camera points fits ({mirrored * 1000:.1f} mm): an axis "
                           "has the wrong sign or two columns are swapped", max_rmse_m=max_rmse_m)
    raise PoorFitError(f"{head}: the pairs are not the same physical points (a mis-detected marker, rows out of "
                       "order?)", max_rmse_m=max_rmse_m)


def residuals(cal: Calibration, camera: np.ndarray, robot: np.ndarray) -> np.ndarray:
    """Per-pair Euclidean error (m) of a calibration."""
    return np.linalg.norm(cal.apply(camera) - robot, axis=1)


def write_pairs(path: str | Path, camera: np.ndarray, robot: np.ndarray) -> None:
    """pairs.csv (HEADER, metres), written atomically."""
    rows = [",".join(HEADER)] + [",".join(f"{v:.6f}" for v in (*c, *r)) for c, r in zip(camera, robot)]
    atomic_write(path, "\n".join(rows) + "\n")


def leave_one_out(camera: np.ndarray, robot: np.ndarray) -> np.ndarray:
    """Each pair's error (m) under the fit of all the OTHER pairs: what the calibration would get
    wrong at that point had it not been measured (a mis-detected pair stands out here, while the
    full fit spreads its error over every residual). NaN for a pair without which the others are
    collinear: no fit, so no error.

    The same as kabsch on each N-1 pairs, in closed form: the sums a fit needs (of c r^T, c, r)
    less pair i, and all N 3x3 SVDs at once, so thousands of pairs take milliseconds."""
    camera, robot = np.asarray(camera, np.float64), np.asarray(robot, np.float64)
    if camera.shape != robot.shape or camera.ndim != 2 or camera.shape[1] != 3:
        raise CalibrationError("camera and robot points must be two [N, 3] arrays of the same length")
    if len(camera) <= MIN_PAIRS:
        raise CalibrationError(f"leave-one-out needs at least {MIN_PAIRS + 1} point pairs, got {len(camera)}")
    if not (np.isfinite(camera).all() and np.isfinite(robot).all()):
        raise CalibrationError("point pairs contain NaN or infinite values")
    _check_spread(camera, "camera")
    _check_spread(robot, "robot")
    n = len(camera)
    c, r = camera - camera.mean(0), robot - robot.mean(0)  # centred, so that no precision is lost to far points
    mean_c, mean_r = (c.sum(0) - c) / (n - 1), (r.sum(0) - r) / (n - 1)  # [N, 3]: the means without pair i
    H = c.T @ r - _outer(c, r) - (n - 1) * _outer(mean_c, mean_r)  # [N, 3, 3]: each one's cross-covariance
    U, _, Vt = np.linalg.svd(H)
    V, Ut = np.swapaxes(Vt, 1, 2), np.swapaxes(U, 1, 2)
    d = np.where(np.linalg.det(V @ Ut) < 0, -1.0, 1.0)
    R = V @ (np.stack([np.ones(n), np.ones(n), d], 1)[:, :, None] * Ut)  # V diag(1, 1, d) U^T
    predicted = np.einsum("nij,nj->ni", R, c - mean_c) + mean_r
    errors = np.linalg.norm(predicted - r, axis=1)
    errors[_collinear_without_each(c) | _collinear_without_each(r)] = np.nan
    return errors


def _outer(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """[N, 3, 3]: a_i b_i^T for each row i."""
    return a[:, :, None] * b[:, None, :]


def _collinear_without_each(points: np.ndarray) -> np.ndarray:
    """[N] bool: whether the points other than point i are collinear (_check_spread's test, on the
    scatter matrix of those N-1 points)."""
    n = len(points)
    mean = (points.sum(0) - points) / (n - 1)
    scatter = points.T @ points - _outer(points, points) - (n - 1) * _outer(mean, mean)
    s = np.sqrt(np.clip(np.linalg.eigvalsh(scatter)[:, ::-1], 0, None))  # singular values, largest first
    return (s[:, 0] < 1e-6) | (s[:, 1] < 1e-3 * s[:, 0])


def outliers(loo: np.ndarray, factor: float = 4.0, floor_m: float = 0.01) -> list[int]:
    """Pairs whose leave-one-out error is more than FACTOR times the median and above FLOOR_M (the
    1 cm the thesis budgets for calibration: below it a pair is noise, not a mis-detection). A NaN
    error (no fit without that pair) is neither counted in the median nor flagged."""
    loo = np.asarray(loo, np.float64)
    known = loo[np.isfinite(loo)]
    if not len(known):
        return []
    bound = max(factor * float(np.median(known)), floor_m)
    return [i for i, e in enumerate(loo) if e > bound]


def check_subset_sizes(sizes: list[int], n_pairs: int) -> None:
    """Refuse a subset size that cannot be fitted (below MIN_PAIRS) or measured (no pair left out)."""
    for k in sizes:
        if not MIN_PAIRS <= k < n_pairs:
            raise ParameterError(f"{{sizes}}: a subset needs {MIN_PAIRS} or more pairs and fewer than the {n_pairs} "
                                 "given (the rest measure it)", sizes=k)


def subset_errors(camera: np.ndarray, robot: np.ndarray, sizes: list[int], trials: int = 200,
                  seed: int = 0) -> dict[int, dict]:
    """Thesis Table 5.2 from the user's own pairs: for each size K, fit TRIALS random K-pair
    subsets and measure each fit on the pairs it did not see; mean and p95 of that error (mm)."""
    camera, robot = np.asarray(camera, np.float64), np.asarray(robot, np.float64)
    rng = np.random.default_rng(seed)
    table = {}
    check_subset_sizes(sizes, len(camera))
    for k in sizes:
        errs = []
        for _ in range(trials):
            pick = np.zeros(len(camera), bool)
            pick[rng.choice(len(camera), k, replace=False)] = True
            try:
                cal = kabsch(camera[pick], robot[pick])
            except CalibrationError:  # a collinear draw: no fit, as a user would redraw
                continue
            errs.append(residuals(cal, camera[~pick], robot[~pick]))
        e = np.concatenate(errs) * 1000 if errs else np.array([np.nan])
        table[k] = {"fits": len(errs), "mean_mm": round(float(e.mean()), 2),
                    "p95_mm": round(float(np.percentile(e, 95)), 2)}
    return table
