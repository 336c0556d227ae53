"""`edgepick calibrate` (fit and collect) and a calibration file given to `grasp`: a user's
mistake ends in exit status 2 and one line starting "edgepick: error: ", with no traceback and
nothing written; a large but valid pairs file is fitted whole.

Run in-process through `edgepick.cli.run` with the file descriptors captured, as
tests/cli/test_bad_input.py does.
"""

from __future__ import annotations

import json
import os

import cv2
import numpy as np
import pytest

from edgepick.cli import run
from edgepick.geometry import Intrinsics
from edgepick.runtime.calibration import HEADER, write_pairs

R_CELL = np.array([[0, -1, 0], [-1, 0, 0], [0, 0, -1]], float)
REGION = "0.18,0.38,-0.16,0.16,0.08,0.24"


def _tree(root) -> dict[str, bytes]:
    """Every file under ROOT with its content, and every folder."""
    found = {}
    for d, dirs, files in os.walk(root):
        for name in dirs:
            found[os.path.relpath(os.path.join(d, name), root)] = b"<folder>"
        for name in files:
            with open(os.path.join(d, name), "rb") as f:
                found[os.path.relpath(os.path.join(d, name), root)] = f.read()
    return found


def _pairs(path, n=8, seed=0):
    rng = np.random.default_rng(seed)
    cam = rng.uniform(-0.2, 0.2, (n, 3)) + [0, 0, 0.6]
    write_pairs(path, cam, cam @ R_CELL.T + [0.3, 0.1, 0.7] + rng.normal(0, 0.001, (n, 3)))
    return path


def _frames(folder, count: int) -> str:
    """A dir: camera of COUNT grey frames (no marker), 320x240, with their intrinsics."""
    for sub in ("rgb", "depth"):
        (folder / sub).mkdir(parents=True)
    (folder / "intrinsics.json").write_text(json.dumps(Intrinsics.d415(320, 240).to_dict()))
    for i in range(count):
        cv2.imwrite(str(folder / "rgb" / f"{i:03d}.png"), np.full((240, 320, 3), 128, np.uint8))
        cv2.imwrite(str(folder / "depth" / f"{i:03d}.png"), np.full((240, 320), 600, np.uint16))
    return f"dir:{folder}"


def _refused(capfd, tmp_path, args: list[str], needle: str) -> str:
    """Run ARGS; it must exit 2 with one error line holding NEEDLE and leave TMP_PATH as it was."""
    before = _tree(tmp_path)
    code = run(args)
    out, err = capfd.readouterr()
    errors = [line for line in err.splitlines() if line.startswith("edgepick: error: ")]
    assert code == 2 and "Traceback" not in err, err
    assert len(errors) == 1 and err.strip().splitlines()[-1] == errors[0], err
    assert needle in errors[0], errors[0]
    assert out == ""
    assert _tree(tmp_path) == before, "something was written"
    return err


GOOD_ROWS = "0.1,0.2,0.5,0.3,0.1,0.2\n0.2,0.1,0.6,0.2,0.3,0.1\n"


@pytest.mark.parametrize("content, needle", [
    (b"\x89PNG\r\n\x1a\n\0\0\0\rIHDR\0\0\0\x10", "is not a text file"),
    (f"# Kalibrierung f\u00fcr Zelle 3\n{','.join(HEADER)}\n{GOOD_ROWS}".encode("latin-1"), "is not UTF-8 text"),
    (f"{','.join(HEADER)}\n{GOOD_ROWS}0.1,{'1' * 200_000}\n".encode(), "is not a CSV file"),
    (f"{','.join(HEADER)}\n{GOOD_ROWS}0.1,0.2,0.5,0.3,0.1,0.2,0.3\n".encode(), "line 4: expected 6 values, got 7"),
])
def test_fit_of_a_pairs_file_that_is_not_pairs_is_one_line(tmp_path, capfd, content, needle):
    (tmp_path / "pairs.csv").write_bytes(content)
    err = _refused(capfd, tmp_path, ["calibrate", str(tmp_path / "pairs.csv"), "--out", str(tmp_path / "calib.json")],
                   needle)
    assert str(tmp_path / "pairs.csv") in err


@pytest.mark.parametrize("out", ["pairs.csv", "./sub/../pairs.csv", "{tmp}/pairs.csv"])
def test_fit_refuses_to_write_over_its_pairs(tmp_path, capfd, monkeypatch, out):
    monkeypatch.chdir(tmp_path)
    _pairs(tmp_path / "pairs.csv")
    (tmp_path / "sub").mkdir()
    _refused(capfd, tmp_path, ["calibrate", "pairs.csv", "--out", out.format(tmp=tmp_path)],
             "write the output elsewhere")


def test_fit_of_pairs_where_one_holds_the_rest_off_a_line_prints_no_leave_one_out_for_it(tmp_path, capfd):
    cam = np.array([[0.0, 0, 0.5], [0.1, 0, 0.5], [0.2, 0, 0.5], [0.3, 0, 0.5], [0.1, 0.1, 0.6]])
    write_pairs(tmp_path / "pairs.csv", cam, cam @ R_CELL.T + [0.3, 0.1, 0.7])
    assert run(["calibrate", str(tmp_path / "pairs.csv"), "--out", str(tmp_path / "calib.json")]) == 0
    out, err = capfd.readouterr()
    report = json.loads(out)
    assert report["leave_one_out_mm"][4] is None and report["outliers"] == []
    assert "pair   5: residual    0.00 mm   leave-one-out       - mm" in err.splitlines()


def test_fit_of_3000_pairs_finishes(tmp_path, capfd):
    rng = np.random.default_rng(3)
    cam = rng.uniform([-0.3, -0.2, 0.4], [0.3, 0.2, 0.9], (3000, 3))
    rob = cam @ R_CELL.T + [0.3, 0.1, 0.7] + rng.normal(0, 0.001, cam.shape)
    rob[42] += [0.03, 0.0, 0.0]  # a mis-detected marker
    write_pairs(tmp_path / "pairs.csv", cam, rob)
    assert run(["calibrate", str(tmp_path / "pairs.csv"), "--out", str(tmp_path / "calib.json"), "--drop-outliers",
                "--subsets", "4,2998"]) == 0
    out, err = capfd.readouterr()
    report = json.loads(out)
    assert report["outliers"] == [43] and report["n_pairs"] == 2999 and len(report["leave_one_out_mm"]) == 3000
    assert err.count("residual") == 3000 and report["subsets"]["2998"]["fits"] == 200
    assert json.loads((tmp_path / "calib.json").read_text())["n_pairs"] == 2999


def test_collect_refuses_a_billion_poses_up_front_saying_how_long(tmp_path, capfd):
    err = _refused(capfd, tmp_path, ["calibrate", "collect", "--poses", "1000000000", "--out",
                                     str(tmp_path / "pairs.csv")], "--poses 1000000000: at most 1000")
    assert " h in all" in err and "--settle 0.5" in err and "--speed 0.1" in err


def test_collect_with_fewer_frames_than_positions_is_one_line(tmp_path, capfd):
    camera = _frames(tmp_path / "frames", 2)
    _refused(capfd, tmp_path, ["calibrate", "collect", "--camera", camera, "--region", REGION, "--poses", "6",
                               "--settle", "0", "--out", str(tmp_path / "pairs.csv")], "2 frames for 6 positions")


def test_collect_with_frames_that_show_no_marker_is_one_line(tmp_path, capfd):
    camera = _frames(tmp_path / "frames", 6)
    err = _refused(capfd, tmp_path, ["calibrate", "collect", "--camera", camera, "--region", REGION, "--poses", "6",
                                     "--settle", "0", "--out", str(tmp_path / "pairs.csv")], "only 0 usable pairs")
    assert err.count("marker not seen") >= 6


def test_collect_refuses_the_same_file_as_out_and_robot_log(tmp_path, capfd, monkeypatch):
    monkeypatch.chdir(tmp_path)
    _refused(capfd, tmp_path, ["calibrate", "collect", "--poses", "6", "--settle", "0", "--out", "x.csv",
                               "--robot-log", "./x.csv"], "--robot-log ./x.csv is the same path as x.csv")


def test_collect_refuses_to_write_over_a_file_of_its_camera_folder(tmp_path, capfd):
    camera = _frames(tmp_path / "frames", 6)
    _refused(capfd, tmp_path, ["calibrate", "collect", "--camera", camera, "--region", REGION, "--poses", "6",
                               "--settle", "0", "--out", str(tmp_path / "frames" / "intrinsics.json")],
             "would overwrite a file of the input")


@pytest.mark.parametrize("content, needle", [
    (b"\0\0binary calibration", "is not a text file"),
    (b'{"R": [[1, 0, 0], [0, 1, 0], [0, 0, NaN]], "t": [0, 0, 0]}', "not valid JSON"),
    (b'{"R": "eye(3)", "t": [0, 0, 0]}', "R must be a list"),
    (b'{"R": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "t": [0, 0, 0], "n_pairs": "12"}', "n_pairs must be a number"),
    (b'{"R": [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "t": [0, 0, 0], "rmse_m": -1}', "rmse_m must be 0 or more"),
])
def test_grasp_with_a_malformed_calibration_is_one_line(tmp_path, capfd, content, needle):
    (tmp_path / "calib.json").write_bytes(content)
    (tmp_path / "intr.json").write_text(json.dumps(Intrinsics.d415(320, 240).to_dict()))
    labels = np.zeros((240, 320), np.uint8)
    cv2.rectangle(labels, (100, 80), (160, 120), 4, -1)
    cv2.imwrite(str(tmp_path / "mask.png"), labels)
    cv2.imwrite(str(tmp_path / "depth.png"), np.full((240, 320), 600, np.uint16))
    err = _refused(capfd, tmp_path, ["grasp", "--mask", str(tmp_path / "mask.png"), "--depth",
                                     str(tmp_path / "depth.png"), "--intrinsics", str(tmp_path / "intr.json"),
                                     "--calib", str(tmp_path / "calib.json")], needle)
    assert str(tmp_path / "calib.json") in err


def test_fit_refuses_subsets_as_large_as_the_pairs_before_fitting(tmp_path, capfd):
    _pairs(tmp_path / "pairs.csv", n=8)
    err = _refused(capfd, tmp_path, ["calibrate", str(tmp_path / "pairs.csv"), "--out", str(tmp_path / "calib.json"),
                                     "--subsets", "4,8"], "--subsets 8: a subset needs 4 or more pairs and fewer than "
                                                          "the 8")
    assert len(err.splitlines()) == 1  # refused before the fit prints its residuals
