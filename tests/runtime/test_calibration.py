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


def _loop_leave_one_out(cam, rob, which=None):
    """The definition: kabsch on every N-1 pairs (NaN where those cannot be fitted)."""
    which = range(len(cam)) if which is None else which
    errors = []
    for i in which:
        keep = np.arange(len(cam)) != i
        try:
            cal = kabsch(cam[keep], rob[keep])
        except CalibrationError:
            errors.append(np.nan)
            continue
        errors.append(float(np.linalg.norm(cal.apply(cam[i]) - rob[i])))
    return np.array(errors)


@given(st.integers(0, 10_000), st.integers(5, 40), st.sampled_from([0.0, 0.001, 0.01, 0.1]))
@settings(max_examples=60, deadline=None)
def test_leave_one_out_equals_a_refit_without_each_pair(seed, n, noise):
    from edgepick.runtime.calibration import leave_one_out

    cam, rob, _, _ = _pairs(np.random.default_rng(seed), n, noise)
    rob[0] += 0.05  # a mis-detected pair as well
    assert np.allclose(leave_one_out(cam, rob), _loop_leave_one_out(cam, rob), rtol=0, atol=1e-9)


def test_leave_one_out_of_3000_pairs_agrees_with_refits():
    from edgepick.runtime.calibration import leave_one_out

    cam, rob, _, _ = _pairs(np.random.default_rng(7), 3000, noise=0.002)
    rob[123] += [0.0, 0.0, 0.04]
    loo = leave_one_out(cam, rob)
    some = [0, 1, 123, 1500, 2999]
    assert loo.shape == (3000,) and np.allclose(loo[some], _loop_leave_one_out(cam, rob, some), rtol=0, atol=1e-9)


def test_a_pair_without_which_the_rest_are_collinear_has_no_leave_one_out_error():
    from edgepick.runtime.calibration import leave_one_out, outliers

    cam = np.array([[0.0, 0, 0.5], [0.1, 0, 0.5], [0.2, 0, 0.5], [0.3, 0, 0.5], [0.1, 0.1, 0.6]])
    rob = cam @ np.diag([1.0, -1, -1]) + [0.3, 0.0, 0.7]
    loo = leave_one_out(cam, rob)
    assert np.isnan(loo[4]) and np.isfinite(loo[:4]).all() and loo[:4].max() < 1e-9
    assert np.isnan(_loop_leave_one_out(cam, rob)[4])
    assert outliers(loo) == []


def test_outliers_skip_nan_and_still_flag_the_rest():
    from edgepick.runtime.calibration import outliers

    assert outliers(np.array([0.001, 0.002, np.nan, 0.0015, 0.05])) == [4]
    assert outliers(np.array([np.nan] * 5)) == []


def test_subset_errors_of_3000_pairs():
    from edgepick.runtime.calibration import subset_errors

    cam, rob, _, _ = _pairs(np.random.default_rng(8), 3000, noise=0.001)
    table = subset_errors(cam, rob, [4, 2999], trials=20)
    assert table[4]["fits"] == table[2999]["fits"] == 20 and table[2999]["mean_mm"] < table[4]["mean_mm"]


GOOD = "\n".join([",".join(HEADER), "0.1,0.2,0.5,0.3,0.1,0.2", "0.2,0.1,0.6,0.2,0.3,0.1"]) + "\n"


@pytest.mark.parametrize("content, needle", [
    (b"\x89PNG\r\n\x1a\n\0\0\0\rIHDR", "not a text file"),
    (("# Kalibrierung f\u00fcr Zelle 3\n" + GOOD).encode("latin-1"), "not UTF-8"),
    (GOOD.encode() + b"0.1," + b"1" * 200_000 + b"\n", "not a CSV file"),
    (GOOD.encode() + b"0.1,0.2,0.5,0.3,0.1,0.2,\n", "line 4: expected 6 values, got 7"),
    (GOOD.encode() + b"0.1,0.2,0.5\n", "line 4: expected 6 values, got 3"),
    (GOOD.encode() + b"0.1,0.2,0.5,0.3,,0.2\n", "line 4: not six numbers"),
    (GOOD.encode() + b"0.1,0.2,\"0.5\n0.3\",0.1,0.2,0.3\n", "line 4: not six numbers"),
    (b"", "must start with the header"),
    (b"x,y,z,a,b,c\n", "must start with the header"),
])
def test_read_pairs_refuses_any_other_content_in_one_line(tmp_path, content, needle):
    from edgepick.errors import EdgepickError

    (tmp_path / "p.csv").write_bytes(content)
    with pytest.raises(EdgepickError) as info:
        read_pairs(tmp_path / "p.csv")
    message = str(info.value)
    assert needle in message and str(tmp_path / "p.csv") in message and "\n" not in message


def test_read_pairs_takes_a_spreadsheet_header_with_bom_case_and_spaces(tmp_path):
    header = " CAM_X, Cam_Y ,cam_z,ROBOT_X,robot_y , robot_z"
    (tmp_path / "p.csv").write_bytes(("\ufeff" + header + "\r\n" + GOOD.split("\n", 1)[1].replace("\n", "\r\n"))
                                     .encode())
    cam, rob = read_pairs(tmp_path / "p.csv")
    assert cam.shape == rob.shape == (2, 3) and cam[1].tolist() == [0.2, 0.1, 0.6]


@given(st.binary(max_size=300) | st.text(alphabet=",.-0123456789eEnaif \"\r\n\0", max_size=300))
@settings(max_examples=300, deadline=None)
def test_read_pairs_of_any_content_gives_pairs_or_one_line(content):
    import tempfile

    from edgepick.errors import EdgepickError

    with tempfile.TemporaryDirectory() as folder:
        path = f"{folder}/p.csv"
        with open(path, "wb") as f:
            f.write((",".join(HEADER) + "\n").encode() + (content if isinstance(content, bytes) else content.encode()))
        try:
            cam, rob = read_pairs(path)
        except EdgepickError as exc:
            assert "\n" not in str(exc) and path in str(exc)
        else:
            assert cam.shape == rob.shape and cam.shape[1] == 3 and np.isfinite(cam).all()


CALIB = {"R": [[0, -1, 0], [-1, 0, 0], [0, 0, -1]], "t": [0.28, 0.0, 0.7], "rmse_m": 0.001, "n_pairs": 12}
DROP = object()  # a field left out of the file


def _calib(**change) -> str:
    return json.dumps({k: v for k, v in {**CALIB, **change}.items() if v is not DROP})


@pytest.mark.parametrize("content, needle", [
    (b"\0\1\2binary", "not a text file"),
    ("R \u00e9".encode("latin-1"), "not UTF-8"),
    (b'{"R": NaN}', "not valid JSON"),
    (b"[1, 2]", "must be a JSON object"),
    (_calib(R="identity"), "R must be a list, got the string 'identity'"),
    (_calib(R=[[1, 0, 0], [0, 1, 0]]), "R must be a list of 3, got 2"),
    (_calib(R=[[1, 0, 0], [0, 1, 0], [0, 0, "1"]]), "R[2][2] must be a number"),
    (_calib(R=[[1, 0, 0], [0, 1, 0], [0, 0, 1]]).replace("1]]", "1e400]]"), "R[2][2] must be a finite number"),
    (_calib(t=None), "t must be a list, got null"),
    (_calib(t=[0, 0]), "t must be a list of 3"),
    (_calib(n_pairs="12"), "n_pairs must be a number, got the string '12'"),
    (_calib(n_pairs=-3), "n_pairs must be 0 or more"),
    (_calib(n_pairs=4.5), "n_pairs must be a whole number"),
    (_calib(n_pairs=True), "n_pairs must be a number, got true"),
    (_calib(rmse_m=-0.001), "rmse_m must be 0 or more"),
    (_calib(rmse_m=[0.1]), "rmse_m must be a number"),
    (_calib(rmse_m=None), "rmse_m must be a number, got null"),
    (_calib(R=DROP), "has no field 'R'"),
    (_calib(R=np.diag([1, 1, -1]).tolist()), "not a proper rotation"),
])
def test_calibration_load_refuses_malformed_files_naming_file_and_field(tmp_path, content, needle):
    from edgepick.errors import EdgepickError

    path = tmp_path / "calib.json"
    path.write_bytes(content if isinstance(content, bytes) else content.encode())
    with pytest.raises(EdgepickError) as info:
        Calibration.load(path)
    message = str(info.value)
    assert needle in message and str(path) in message and "\n" not in message


def test_calibration_load_reads_a_good_file_and_one_without_the_optional_fields(tmp_path):
    (tmp_path / "a.json").write_text(json.dumps(CALIB))
    (tmp_path / "b.json").write_text(json.dumps({"R": CALIB["R"], "t": CALIB["t"]}))
    a, b = Calibration.load(tmp_path / "a.json"), Calibration.load(tmp_path / "b.json")
    assert a.n_pairs == 12 and a.rmse_m == 0.001 and b.n_pairs == 0 and np.isnan(b.rmse_m)
    assert np.allclose(a.apply([0.0, 0.0, 0.5]), [0.28, 0.0, 0.2])
