"""SIGTERM (what `timeout`, systemd and a closing terminal send) is an interrupt like Ctrl-C: each
long command, stopped half-way, exits 128 + 15 with nothing half-written left behind, and
`data synth` stops its worker processes within seconds, for SIGTERM and for a terminal's Ctrl-C.

Each command runs as a user starts it (a subprocess in its own session, like a job in a shell);
the signal goes out once the command is visibly at work (its temporary output has appeared).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.conftest import REPO

START_S = 240  # a loaded 2-core machine starts Python and torch slowly


def _start(*args: str, cwd: Path = REPO) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "edgepick", *args], cwd=cwd, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True, start_new_session=True,
                            env={**os.environ, "EDGEPICK_PROGRESS_S": "1"},  # a progress line within a second
                            # a shell that runs the suite in the background ignores SIGINT, and children
                            # inherit that: give the child the default disposition, as a terminal would
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))


def _wait_for(proc: subprocess.Popen, ready, what: str) -> None:
    deadline = time.monotonic() + START_S
    while time.monotonic() < deadline and proc.poll() is None and not ready():
        time.sleep(0.05)
    if proc.poll() is not None:
        raise AssertionError(f"the command ended before {what}: {proc.stderr.read()[-2000:]}")
    assert ready(), f"no sign of {what} within {START_S} s"


def _group_alive(pgid: int) -> bool:
    try:
        os.killpg(pgid, 0)
        return True
    except ProcessLookupError:
        return False


def _stop(proc: subprocess.Popen, sig: int, group: bool = False) -> tuple[int, str, float]:
    """Send SIG (to the whole session's group, as a terminal's Ctrl-C does, when GROUP) and wait
    until every process of the group is gone; returns the exit status, stderr and the seconds taken."""
    t0 = time.monotonic()
    if group:
        os.killpg(proc.pid, sig)
    else:
        proc.send_signal(sig)
    _, err = proc.communicate(timeout=60)
    while _group_alive(proc.pid) and time.monotonic() - t0 < 30:
        time.sleep(0.05)
    return proc.returncode, err, time.monotonic() - t0


def _partial(folder: Path, pattern: str) -> list[Path]:
    return list(folder.glob(pattern))


def _importing_workers(pgid: int) -> int:
    """How many multiprocessing workers of the group PGID have Python's own SIGINT handler (a
    KeyboardInterrupt), as they have from Python's start until they set their own disposition."""
    count = 0
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
            if int(fields[2]) != pgid or b"spawn_main" not in (stat.parent / "cmdline").read_bytes():
                continue
            caught = next(line for line in (stat.parent / "status").read_text().splitlines()
                          if line.startswith("SigCgt:"))
            count += bool(int(caught.split()[1], 16) & (1 << (signal.SIGINT - 1)))
        except (OSError, IndexError, ValueError, StopIteration):  # a process that ended meanwhile
            continue
    return count


@pytest.mark.parametrize("sig, group, code", [(signal.SIGTERM, False, 143), (signal.SIGINT, True, 130)],
                         ids=["SIGTERM", "Ctrl-C to the group"])
def test_data_synth_with_workers_stops_them_within_5_s_and_leaves_nothing(tmp_path, sig, group, code):
    proc = _start("data", "synth", str(tmp_path / "data"), "--scenes", "3000", "--workers", "2", "--size", "320x240")
    _wait_for(proc, lambda: sum(len(list(p.glob("*/rgb/*.png"))) for p in _partial(tmp_path, ".data.partial-*")) >= 4,
              "scenes being written")
    status, err, seconds = _stop(proc, sig, group)
    assert status == code, err
    assert seconds <= 5, f"the workers took {seconds:.1f} s to stop"
    assert not _group_alive(proc.pid), "a worker process outlived data synth"
    assert list(tmp_path.iterdir()) == []
    assert "Traceback" not in err and err.strip().splitlines()[-1].startswith("edgepick: ")


@pytest.mark.parametrize("sig, group, code", [(signal.SIGTERM, False, 143), (signal.SIGINT, True, 130)],
                         ids=["SIGTERM", "Ctrl-C to the group"])
def test_data_synth_stopped_while_its_workers_start_stops_quietly(tmp_path, sig, group, code):
    """The workers take seconds to import: a signal then must neither print a worker's traceback
    nor catch the parent half-way through starting them."""
    proc = _start("data", "synth", str(tmp_path / "data"), "--scenes", "3000", "--workers", "2", "--size", "320x240")
    _wait_for(proc, lambda: _importing_workers(proc.pid) >= 1, "a worker process importing")
    status, err, seconds = _stop(proc, sig, group)
    assert status == code, err
    assert seconds <= 5, f"the workers took {seconds:.1f} s to stop"
    assert not _group_alive(proc.pid), "a worker process outlived data synth"
    assert list(tmp_path.iterdir()) == []
    assert "Traceback" not in err and err.strip().splitlines()[-1].startswith("edgepick: "), err


def test_data_capture_terminated_leaves_no_folder(tmp_path):
    proc = _start("data", "capture", str(tmp_path / "cap"), "--camera", "synth", "--count", "50", "--interval", "0.5",
                  "--size", "160x120")
    _wait_for(proc, lambda: any(len(list(p.glob("rgb/*.png"))) for p in _partial(tmp_path, ".cap.partial-*")),
              "frames being written")
    status, err, _ = _stop(proc, signal.SIGTERM)
    assert status == 143, err
    assert err.strip().splitlines()[-1] == "edgepick: terminated (SIGTERM)"
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
def test_export_terminated_leaves_no_file(tmp_path, trained_run):
    proc = _start("export", str(trained_run), "--out", str(tmp_path / "m.onnx"))
    _wait_for(proc, lambda: bool(_partial(tmp_path, ".m.*.tmp.onnx")), "the export's temporary file")
    status, err, _ = _stop(proc, signal.SIGTERM)
    assert status == 143, err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
def test_train_terminated_in_its_first_epoch_leaves_no_run(tmp_path, small_data):
    proc = _start("train", str(small_data), "--out", str(tmp_path / "run"), "--size", "96x64", "--epochs", "50",
                  "--epoch-images", "4000", "--device", "cpu")  # an epoch long enough to report progress within it
    _wait_for(proc, lambda: "epoch 1/50:" in (proc.stderr.readline() or ""), "the first epoch's progress line")
    status, err, _ = _stop(proc, signal.SIGTERM)
    assert status == 143, err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
def test_demo_terminated_removes_the_folder_it_made(tmp_path):
    proc = _start("demo", "--workdir", str(tmp_path / "demo"), "--scenes", "30")
    _wait_for(proc, lambda: bool(_partial(tmp_path / "demo", ".data.partial-*")), "the demo's data being written")
    status, err, _ = _stop(proc, signal.SIGTERM)
    assert status == 143, err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("sig, group, code, name", [(signal.SIGTERM, False, 143, "SIGTERM"),
                                                     (signal.SIGINT, True, 130, "SIGINT")],
                         ids=["SIGTERM", "Ctrl-C to the group"])
def test_pick_stopped_prints_the_summary_of_the_cycles_it_ran(tmp_path, sig, group, code, name):
    """An interrupted pick still says what it did: its JSON summary of every finished cycle on stdout,
    with the signal that ended it, then the exit status of that signal."""
    proc = subprocess.Popen([sys.executable, "-m", "edgepick", "pick", "--cycles", "1000", "--size", "320x240"],
                            cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    seen: list[str] = []
    _wait_for(proc, lambda: sum(line.startswith("cycle ") for line in seen) >= 2 or
              bool(seen.append(proc.stderr.readline())), "two cycles done")
    if group:
        os.killpg(proc.pid, sig)
    else:
        proc.send_signal(sig)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == code, err
    summary = json.loads(out)
    assert summary["interrupted"] == name and summary["halted"] is None
    assert summary["cycles"] == len(summary["results"]) >= 2
    assert [r["cycle"] for r in summary["results"]] == list(range(1, summary["cycles"] + 1))
    assert "Traceback" not in err and err.strip().splitlines()[-1].startswith("edgepick: ")


def test_data_synth_caps_its_workers_at_the_scenes_and_the_cores(tmp_path):
    """--workers 1000 on 3 scenes starts no more processes than there are scenes and cores."""
    from edgepick.data.synth import usable_cores

    proc = subprocess.run([sys.executable, "-m", "edgepick", "data", "synth", str(tmp_path / "d"), "--scenes", "3",
                           "--size", "64x48", "--workers", "1000"], capture_output=True, text=True, timeout=START_S,
                          cwd=REPO)
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["workers"] == min(3, usable_cores())
