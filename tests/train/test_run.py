"""edgepick/train/run.py: the run folder's files are named in one place, and nothing else in the
package or the benchmarks spells them or reads a checkpoint's fields by key."""

from __future__ import annotations

import re

from edgepick.train.run import Run, checkpoint_path
from tests.conftest import REPO

RUN_FILES = re.compile(r"""["'](last\.pt|best\.pt|metrics\.json)["']|epoch_\{|epoch_0\d\d\.pt""")
CHECKPOINT_KEYS = re.compile(r"""\b(ckpt|checkpoint|start|last|resume|best)\[\s*["']""")


def test_a_run_names_its_files_and_lists_its_kept_epochs(tmp_path):
    run = Run(tmp_path / "run")
    assert not run.holds_run() and run.kept_epochs() == []
    run.path.mkdir()
    for name in ("last.pt", "best.pt", "epoch_090.pt", "epoch_095.pt", "epoch_1000.pt", "epoch_x.pt", "notes.txt"):
        (run.path / name).write_text("")
    assert run.holds_run() and run.kept_epochs() == [90, 95, 1000]
    assert run.epoch(95) == run.path / "epoch_095.pt" and run.last.name == "last.pt"
    assert checkpoint_path(run.path) == run.best and checkpoint_path(run.last) == run.last
    assert run.total_train_time_s() is None
    run.write_metrics({"train_time_s": 12.5})
    assert run.total_train_time_s() == 12.5


def test_nothing_but_run_and_checkpoint_knows_the_file_names_or_the_keys():
    allowed = {REPO / "edgepick" / "train" / "run.py", REPO / "edgepick" / "train" / "checkpoint.py"}
    found = []
    for path in sorted([*(REPO / "edgepick").rglob("*.py"), *(REPO / "benchmarks").glob("*.py")]):
        if path in allowed:
            continue
        for n, line in enumerate(path.read_text().splitlines(), start=1):
            code = line.split("#")[0]
            if RUN_FILES.search(code) or CHECKPOINT_KEYS.search(code):
                found.append(f"{path.relative_to(REPO)}:{n}: {line.strip()}")
    assert found == []
