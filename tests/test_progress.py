"""edgepick/progress.py: a long loop says where it is in a log, not only on a terminal."""

from __future__ import annotations

import time

import pytest

from edgepick.progress import StageClock, progress


def test_in_a_log_a_line_every_interval(capsys):
    for _ in progress(range(5), desc="epoch 1/3", unit="batch", every_s=0.0):
        time.sleep(0.001)
    lines = capsys.readouterr().err.splitlines()  # pytest's captured stderr is not a terminal
    assert lines[0].startswith("epoch 1/3: 1/5 batch") and lines[-1].startswith("epoch 1/3: 5/5 batch")


def test_updates_by_hand_and_postfix(capsys):
    bar = progress(total=2, desc="synth", unit="scene", every_s=0.0)
    bar.set_postfix(loss="0.5")
    bar.update()
    bar.close()
    assert capsys.readouterr().err.strip() == "synth: 1/2 scene, 0 s, loss 0.5"


def test_disabled_is_silent(capsys):
    assert list(progress(range(3), desc="x", enabled=False)) == [0, 1, 2]
    assert capsys.readouterr().err == ""


def test_the_log_interval_comes_from_the_environment(monkeypatch, capsys):
    from edgepick.errors import ConfigError
    from edgepick.progress import EVERY_S, log_interval_s

    monkeypatch.delenv("EDGEPICK_PROGRESS_S", raising=False)
    assert log_interval_s() == EVERY_S
    monkeypatch.setenv("EDGEPICK_PROGRESS_S", "0")
    bar = progress(total=2, desc="synth", unit="scene")  # no every_s: the environment's
    bar.update()
    assert capsys.readouterr().err.startswith("synth: 1/2 scene")
    for bad in ("soon", "-1", "nan"):
        monkeypatch.setenv("EDGEPICK_PROGRESS_S", bad)
        with pytest.raises(ConfigError, match="EDGEPICK_PROGRESS_S"):
            log_interval_s()


def test_a_bad_interval_is_refused_in_one_line_before_any_work(monkeypatch, capsys, tmp_path):
    from edgepick.cli import run

    monkeypatch.setenv("EDGEPICK_PROGRESS_S", "soon")
    assert run(["data", "synth", str(tmp_path / "data"), "--scenes", "30"]) == 2
    assert list(tmp_path.iterdir()) == []
    err = capsys.readouterr().err.strip()
    assert err.startswith("edgepick: error: EDGEPICK_PROGRESS_S='soon'") and len(err.splitlines()) == 1


def test_a_stage_that_comes_back_is_summed_and_a_failing_one_still_counted():
    clock = StageClock()
    with clock("calibrate"):
        time.sleep(0.02)
    with clock("write"):
        pass
    with pytest.raises(RuntimeError), clock("calibrate"):
        time.sleep(0.02)
        raise RuntimeError("boom")
    seconds = clock.to_dict()
    assert list(seconds) == ["calibrate", "write"]
    assert seconds["calibrate"] >= 0.04 and seconds["write"] < seconds["calibrate"]
    total = StageClock()
    total.add({"prepare": 1.0, "calibrate": 2.0})
    total.add(seconds)
    assert total.to_dict() == {"prepare": 1.0, "calibrate": round(2.0 + clock.seconds["calibrate"], 3),
                               "write": seconds["write"]}
