"""`edgepick calibrate`: the camera-to-robot transform from point pairs."""

from __future__ import annotations

import math

import click

from edgepick.cli.options import emit
from edgepick.errors import ConfigError
from edgepick.files import check_output


@click.command()
@click.argument("pairs", type=click.Path(dir_okay=False))
@click.option("--out", required=True, type=click.Path(dir_okay=False),
              help="calib.json to write (docs/contracts.md#intrinsics-and-calibration).")
@click.option("--max-rmse", default=20.0, show_default=True, metavar="MM",
              help="Refuse a fit whose RMSE is above this many millimetres (and say what is likely wrong).")
def calibrate(pairs: str, out: str, max_rmse: float) -> None:
    """Fit the camera-to-robot transform (Kabsch, det = +1) from PAIRS.csv.

    PAIRS.csv has the header cam_x,cam_y,cam_z,robot_x,robot_y,robot_z (metres) and at
    least 4 rows of the same physical points seen by the camera and touched by the robot.
    Prints the per-pair residuals; refuses coincident or collinear points, and a fit too poor
    to be a measurement (mixed units, a mirrored axis, pairs of different points).
    """
    from edgepick.runtime.calibration import diagnose, kabsch, read_pairs, residuals

    if not (math.isfinite(max_rmse) and max_rmse > 0):
        raise ConfigError(f"--max-rmse {max_rmse}: must be a positive number of millimetres")
    check_output(out, "--out")
    camera, robot = read_pairs(pairs)
    cal = kabsch(camera, robot)
    diagnose(cal, camera, robot, max_rmse / 1000)
    for i, err in enumerate(residuals(cal, camera, robot), start=1):
        click.echo(f"pair {i:3d}: residual {err * 1000:7.2f} mm", err=True)
    click.echo(f"RMSE {cal.rmse_m * 1000:.2f} mm over {cal.n_pairs} pairs", err=True)
    cal.save(out)
    emit({"out": out, **cal.to_dict()})

