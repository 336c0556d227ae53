"""Table 5.5 driver: phases split over runs (--only), finished phases kept with their times."""

import json

from edgepick.bench.table55 import PHASES, SHORT, Setting, make_table55
from edgepick.geometry import Size

TINY = Setting("tiny", splits=(4, 2, 2), size=Size(96, 64), epochs=100, batch_size=2, lr=2e-3, runs=2)


def test_only_runs_the_named_phases_and_keeps_finished_ones(tmp_path):
    work = tmp_path / "work"
    assert make_table55(work, TINY, "cpu", "first", echo=lambda line: None, only={"synth"}) is None
    state = json.loads((work / "phases.json").read_text())
    assert set(state["times"]) == {"synth"} and state["commands"] == ["first"]
    assert not (work / "float").exists()  # not asked for
    meta = (work / "data" / "meta.json").stat().st_mtime_ns
    echoed = []
    assert make_table55(work, TINY, "cpu", "second", echo=echoed.append, only={"synth"}) is None
    assert echoed == [] and (work / "data" / "meta.json").stat().st_mtime_ns == meta  # kept, not redone
    state = json.loads((work / "phases.json").read_text())
    assert set(state["times"]) == {"synth"} and state["commands"] == ["first", "second"]


def test_short_gpu_setting_switches_at_whole_epochs():
    assert {"hybrid0.01", "hybrid0.05", "hybrid0.10"} <= set(PHASES)
    assert SHORT.splits == (4000, 1000, 100) and SHORT.size == Size(640, 480)
    assert [round((1 - p) * SHORT.epochs) for p in (0.01, 0.05, 0.10)] == [99, 95, 90]
    assert "160 images drawn afresh" in SHORT.describe()
