"""edgepick/files.py: outputs checked up front, written whole or not at all, with the user's umask."""

from __future__ import annotations

import os
import stat

import pytest

from edgepick.errors import ConfigError
from edgepick.files import atomic_dir, atomic_path, atomic_write, check_output


def _mode(path) -> int:
    return stat.S_IMODE(os.stat(path).st_mode)


@pytest.fixture()
def umask_022():
    old = os.umask(0o022)
    yield
    os.umask(old)


def test_outputs_get_the_users_umask_not_tempfiles_private_modes(tmp_path, umask_022):
    assert _mode(atomic_write(tmp_path / "a" / "calib.json", "{}")) == 0o644  # mkstemp alone gives 0600
    with atomic_path(tmp_path / "m.onnx") as tmp:
        tmp.write_bytes(b"x")
    assert _mode(tmp_path / "m.onnx") == 0o644
    with atomic_dir(tmp_path / "data") as tmp:
        (tmp / "meta.json").write_text("{}")
    assert _mode(tmp_path / "data") == 0o755  # mkdtemp alone gives 0700


def test_a_failed_write_leaves_nothing(tmp_path):
    with pytest.raises(RuntimeError):
        with atomic_path(tmp_path / "m.onnx") as tmp:
            tmp.write_bytes(b"half")
            raise RuntimeError("export failed")
    with pytest.raises(KeyboardInterrupt):
        with atomic_dir(tmp_path / "data") as tmp:
            (tmp / "x").write_text("half")
            raise KeyboardInterrupt
    assert list(tmp_path.iterdir()) == []


def test_an_existing_folder_is_replaced_only_when_the_new_one_is_complete(tmp_path):
    (tmp_path / "data").mkdir()
    (tmp_path / "data" / "old").write_text("old")
    with pytest.raises(RuntimeError):
        with atomic_dir(tmp_path / "data"):
            raise RuntimeError
    assert (tmp_path / "data" / "old").exists()
    with atomic_dir(tmp_path / "data") as tmp:
        (tmp / "new").write_text("new")
    assert [p.name for p in (tmp_path / "data").iterdir()] == ["new"]


@pytest.mark.parametrize("path, kind, suffixes, message", [
    ("afile/out.json", "file", (), "is a file, not a folder"),
    ("afile", "dir", (), "is a file; give a folder"),
    ("adir", "file", (), "is a folder; give a file name"),
    ("model.txt", "file", (".onnx",), "must end in .onnx"),
])
def test_check_output_refuses_with_the_reason(tmp_path, path, kind, suffixes, message):
    (tmp_path / "afile").write_text("x")
    (tmp_path / "adir").mkdir()
    with pytest.raises(ConfigError, match=message):
        check_output(tmp_path / path, "--out", kind=kind, suffixes=suffixes)


def test_check_output_accepts_missing_parents_and_creates_nothing(tmp_path):
    check_output(tmp_path / "a" / "b" / "c.json", "--out")
    check_output(tmp_path / "runs" / "exp1", "--out", kind="dir")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes anywhere")
def test_check_output_refuses_an_unwritable_folder(tmp_path):
    locked = tmp_path / "locked"
    locked.mkdir(mode=0o555)
    with pytest.raises(ConfigError, match="permission denied"):
        check_output(locked / "sub" / "x.json", "--out")
