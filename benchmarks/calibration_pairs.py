"""Thesis Table 5.2 analogue: calibration error against the number of point pairs.

Simulated pairs: camera points spread over a 0.6 x 0.4 m table at 0.45-0.85 m depth, a
random camera-to-robot pose, camera noise like a D415 (sigma ~ 0.8 mm + 3 mm * z^2 in
depth, ~1 px laterally) and robot touch-up error (sigma 1 mm). The error is the mean
Euclidean distance at held-out points, as the thesis measured it at reached points.

    python benchmarks/calibration_pairs.py [--trials 500] [--seed 0]
"""

from __future__ import annotations

import argparse

import numpy as np

from edgepick.runtime.calibration import kabsch


def noisy_camera(rng: np.random.Generator, p: np.ndarray) -> np.ndarray:
    z = p[:, 2:3]
    lateral = z / 615.0  # one pixel at focal length 615 px
    sigma = np.hstack([lateral, lateral, 0.0008 + 0.003 * z ** 2])
    return p + rng.normal(0, 1, p.shape) * sigma


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--trials", type=int, default=500)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--robot-noise-mm", type=float, default=1.0)
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    lo, hi = np.array([-0.3, -0.2, 0.45]), np.array([0.3, 0.2, 0.85])
    print("| # Sample Points | Mean error (mm) | p95 error (mm) | thesis (mm) |")
    print("|---|---|---|---|")
    for n, thesis in ((4, 19), (14, 12), (24, 10)):
        errs = []
        for _ in range(args.trials):
            q, r = np.linalg.qr(rng.standard_normal((3, 3)))
            R = q * np.sign(np.linalg.det(q))
            t = rng.uniform(-0.5, 0.5, 3)
            cam_true = rng.uniform(lo, hi, (n, 3))
            robot = cam_true @ R.T + t + rng.normal(0, args.robot_noise_mm / 1000, (n, 3))
            cal = kabsch(noisy_camera(rng, cam_true), robot)
            probe = rng.uniform(lo, hi, (50, 3))
            errs.append(np.linalg.norm(cal.apply(noisy_camera(rng, probe)) - (probe @ R.T + t), axis=1))
        e = np.concatenate(errs) * 1000
        print(f"| {n} | {e.mean():.1f} | {np.percentile(e, 95):.1f} | {thesis} |")


if __name__ == "__main__":
    main()
