import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from edgepick.runtime.calibration import HEADER, Calibration, CalibrationError, kabsch, read_pairs
from tests.conftest import run_cli


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.standard_normal((3, 3)))
    q = q @ np.diag(np.sign(np.diag(r)))
    return q if np.linalg.det(q) > 0 else -q


def _pairs(rng, n=12, noise=0.0):
    R, t = random_rotation(rng), rng.uniform(-0.5, 0.5, 3)
    cam = rng.uniform([-0.3, -0.2, 0.4], [0.3, 0.2, 0.9], (n, 3))
    robot = cam @ R.T + t + rng.normal(0, noise, (n, 3))
    return cam, robot, R, t


@given(st.integers(0, 10_000))
@settings(max_examples=50, deadline=None)
def test_recovers_random_rigid_transforms_exactly(seed):
    cam, robot, R, t = _pairs(np.random.default_rng(seed))
    cal = kabsch(cam, robot)
    assert np.allclose(cal.R, R, atol=1e-9) and np.allclose(cal.t, t, atol=1e-9)
    assert abs(np.linalg.det(cal.R) - 1) < 1e-9 and cal.rmse_m < 1e-9


def test_with_noise_error_shrinks_with_more_pairs():
    """The shape of thesis Table 5.2: more pairs, smaller error at held-out points."""
    rng = np.random.default_rng(1)
    errs = {}
    for n in (4, 14, 24):
        e = []
        for _ in range(200):
            cam, robot, R, t = _pairs(rng, n, noise=0.005)
            cal = kabsch(cam, robot)
            probe = rng.uniform([-0.3, -0.2, 0.4], [0.3, 0.2, 0.9], (20, 3))
            e.append(np.linalg.norm(cal.apply(probe) - (probe @ R.T + t), axis=1).mean())
        errs[n] = np.mean(e)
    assert errs[4] > errs[14] > errs[24]


def test_reflection_is_never_returned():
    rng = np.random.default_rng(3)
    cam = rng.uniform(-1, 1, (8, 3))
    robot = cam * np.array([1, 1, -1])  # a mirror image: best proper rotation, not the reflection
    cal = kabsch(cam, robot)
    assert abs(np.linalg.det(cal.R) - 1) < 1e-9


@pytest.mark.parametrize("cam,msg", [
    (np.zeros((3, 3)) + np.arange(3)[:, None], "at least 4"),
    (np.array([[0, 0, 0], [1, 1, 1], [2, 2, 2], [3, 3, 3.0]]), "collinear"),
    (np.array([[0, 0, 0], [0, 0, 0], [1, 0, 0], [0, 1, 0.0]]), "coincide"),
    (np.array([[0, 0, np.nan], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]]), "NaN"),
])
def test_degenerate_inputs_refused(cam, msg):
    with pytest.raises(CalibrationError, match=msg):
        kabsch(cam, cam + 0.1)


def _write(path, rows, header=HEADER):
    path.write_text(",".join(header) + "\n" + "\n".join(",".join(str(v) for v in r) for r in rows) + "\n")


def test_cli_writes_contract_file_and_prints_residuals(tmp_path):
    cam, robot, R, t = _pairs(np.random.default_rng(5), 6, noise=0.002)
    _write(tmp_path / "pairs.csv", np.hstack([cam, robot]))
    proc = run_cli("calibrate", str(tmp_path / "pairs.csv"), "--out", str(tmp_path / "calib.json"), check=True)
    calib = json.loads((tmp_path / "calib.json").read_text())
    assert set(calib) == {"R", "t", "rmse_m", "n_pairs"} and calib["n_pairs"] == 6
    assert proc.stderr.count("residual") == 6 and "RMSE" in proc.stderr
    loaded = Calibration.load(tmp_path / "calib.json")
    assert np.allclose(loaded.R, R, atol=0.05)


@pytest.mark.parametrize("rows,header,msg", [
    ([[0, 0, 0, 1, 1, 1]] * 5, HEADER, "coincide"),
    ([[0, 0, 0, 1, 1, 1]], ["x", "y", "z", "a", "b", "c"], "header"),
    ([[0, 0, "nan", 1, 1, 1]], HEADER, "NaN"),
    ([[1, 2, 3]], HEADER, "expected 6"),
])
def test_cli_bad_pairs_exit_2_and_write_nothing(tmp_path, rows, header, msg):
    _write(tmp_path / "pairs.csv", rows, header)
    proc = run_cli("calibrate", str(tmp_path / "pairs.csv"), "--out", str(tmp_path / "calib.json"))
    assert proc.returncode == 2 and msg in proc.stderr and "Traceback" not in proc.stderr
    assert not (tmp_path / "calib.json").exists()


def test_load_refuses_non_rotation(tmp_path):
    (tmp_path / "c.json").write_text(json.dumps({"R": np.diag([1, 1, -1]).tolist(), "t": [0, 0, 0]}))
    with pytest.raises(CalibrationError, match="proper rotation"):
        Calibration.load(tmp_path / "c.json")


def test_read_pairs_round_trip(tmp_path):
    cam, robot, _, _ = _pairs(np.random.default_rng(2), 5)
    _write(tmp_path / "p.csv", np.hstack([cam, robot]))
    c, r = read_pairs(tmp_path / "p.csv")
    assert np.allclose(c, cam) and np.allclose(r, robot)


def test_leave_one_out_flags_a_mis_detected_pair_and_drop_outliers_fits_without_it(tmp_path, capfd):
    from edgepick.cli import run
    from edgepick.runtime.calibration import leave_one_out, outliers, subset_errors, write_pairs

    rng = np.random.default_rng(3)
    cam = rng.uniform([-0.2, -0.15, 0.45], [0.2, 0.15, 0.65], (16, 3))
    R, t = np.array([[0, -1, 0], [-1, 0, 0], [0, 0, -1]], float), np.array([0.28, 0.0, 0.7])
    rob = cam @ R.T + t + rng.normal(0, 0.001, cam.shape)
    rob[5] += [0.0, 0.03, 0.0]  # a marker read 3 cm off
    loo = leave_one_out(cam, rob)
    assert outliers(loo) == [5] and loo[5] > 0.02
    table = subset_errors(cam, rob, [4, 12], trials=50)
    assert set(table) == {4, 12} and table[4]["fits"] == 50
    write_pairs(tmp_path / "p.csv", cam, rob)
    assert run(["calibrate", str(tmp_path / "p.csv"), "--out", str(tmp_path / "all.json")]) == 0
    kept = json.loads(capfd.readouterr().out)
    assert run(["calibrate", str(tmp_path / "p.csv"), "--out", str(tmp_path / "drop.json"), "--drop-outliers"]) == 0
    dropped = json.loads(capfd.readouterr().out)
    assert kept["outliers"] == dropped["outliers"] == [6]  # 1-based, as the pairs are printed
    assert dropped["n_pairs"] == 15 and dropped["rmse_m"] < 0.002 < kept["rmse_m"]
    assert run(["calibrate", str(tmp_path / "p.csv"), "--out", str(tmp_path / "x.json"), "--subsets", "16"]) == 2
    assert "fewer than the 16 given" in capfd.readouterr().err
