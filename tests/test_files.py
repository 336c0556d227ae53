"""edgepick/files.py: outputs checked up front, written whole or not at all, with the user's umask."""

from __future__ import annotations

import os
import socket
import stat

import pytest

from edgepick.errors import ConfigError
from edgepick.files import atomic_dir, atomic_path, atomic_write, check_output, made_by, output_dir


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


def test_a_folder_is_renamed_only_onto_a_new_or_empty_one_and_never_replaces_a_users_folder(tmp_path):
    (tmp_path / "empty").mkdir()
    with atomic_dir(tmp_path / "empty") as tmp:
        (tmp / "new").write_text("new")
    assert [p.name for p in (tmp_path / "empty").iterdir()] == ["new"]
    (tmp_path / "data").mkdir()
    (tmp_path / "data" / "notes.txt").write_text("the user's")
    with pytest.raises(ConfigError, match="not an empty folder"):
        with atomic_dir(tmp_path / "data") as tmp:
            (tmp / "meta.json").write_text("{}")
    assert [p.name for p in (tmp_path / "data").iterdir()] == ["notes.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["data", "empty"]  # no partial folder left


def test_a_file_is_never_renamed_over_a_fifo(tmp_path):
    os.mkfifo(tmp_path / "pipe")
    with pytest.raises(ConfigError, match="FIFO"):
        atomic_write(tmp_path / "pipe", "{}")
    assert stat.S_ISFIFO(os.lstat(tmp_path / "pipe").st_mode)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["pipe"]


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


@pytest.fixture()
def odd_paths(tmp_path):
    """Outputs that are not plain files or folders: links, special files, long names."""
    (tmp_path / "dir").mkdir()
    (tmp_path / "file").write_text("x")
    os.symlink(tmp_path / "dir", tmp_path / "link-to-dir")
    os.symlink(tmp_path / "file", tmp_path / "link-to-file")
    os.symlink(tmp_path / "missing", tmp_path / "dangling")
    os.symlink(tmp_path / "loop", tmp_path / "loop")
    os.mkfifo(tmp_path / "fifo")
    sock = socket.socket(socket.AF_UNIX)
    sock.bind(str(tmp_path / "sock"))
    yield tmp_path
    sock.close()


@pytest.mark.parametrize("name, kind, message", [
    ("link-to-dir", "dir", "is a symbolic link"),
    ("link-to-file", "file", "is a symbolic link"),
    ("dangling", "file", "broken symbolic link"),
    ("loop", "file", "broken symbolic link"),
    ("loop/x.json", "file", "Too many levels of symbolic links"),
    ("fifo", "file", "FIFO"),
    ("sock", "file", "a socket"),
    ("n" * 240 + ".json", "file", "bytes; this file system takes"),
    ("n" * 240, "dir", "bytes; this file system takes"),
])
def test_check_output_refuses_what_is_not_a_plain_file_or_folder(odd_paths, name, kind, message):
    with pytest.raises(ConfigError, match=message):
        check_output(odd_paths / name, "--out", kind=kind)


@pytest.mark.parametrize("path", ["/proc/edgepick.json", "/sys/kernel/x.json", "/dev/null", "/dev/shm/x.json"])
def test_check_output_refuses_kernel_and_device_file_systems(path):
    with pytest.raises(ConfigError, match=r"/proc|/sys|/dev|character device"):
        check_output(path, "--out")


def test_check_output_refuses_a_character_device_made_in_a_test_folder(tmp_path):
    if os.geteuid() != 0:
        pytest.skip("making a device node needs root")
    os.mknod(tmp_path / "full", 0o600 | stat.S_IFCHR, os.makedev(1, 7))  # /dev/full's numbers
    with pytest.raises(ConfigError, match="character device"):
        check_output(tmp_path / "full", "--out")
    with pytest.raises(ConfigError, match="character device"):
        atomic_write(tmp_path / "full", "{}")
    assert stat.S_ISCHR(os.lstat(tmp_path / "full").st_mode)


def test_check_output_refuses_an_empty_path_and_the_working_folder(tmp_path, monkeypatch):
    with pytest.raises(ConfigError, match="--out is empty"):
        check_output("", "--out")
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    for folder in (".", str(work), str(tmp_path), "/"):
        with pytest.raises(ConfigError, match="working folder"):
            check_output(folder, "--out", kind="dir")


def test_check_output_refuses_an_output_that_is_an_input(tmp_path):
    (tmp_path / "pairs.csv").write_text("x")
    (tmp_path / "data").mkdir()
    (tmp_path / "data" / "meta.json").write_text("{}")
    with pytest.raises(ConfigError, match="same path as"):
        check_output(tmp_path / "pairs.csv", "--out", inputs=(tmp_path / "pairs.csv",))
    with pytest.raises(ConfigError, match="same path as"):
        check_output(tmp_path / "log.jsonl", "--robot-log", inputs=(tmp_path / "log.jsonl",))
    with pytest.raises(ConfigError, match="would overwrite a file of the input"):
        check_output(tmp_path / "data" / "meta.json", "--out", inputs=(tmp_path / "data",))
    with pytest.raises(ConfigError, match="holds the input"):
        check_output(tmp_path / "new", "--out", kind="dir", inputs=(tmp_path / "new" / "pairs.csv",))
    check_output(tmp_path / "data" / "sheet.png", "--out", inputs=(tmp_path / "data",))  # a new file beside it


def test_a_non_empty_folder_is_refused_unless_the_same_command_made_it(tmp_path):
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("the user's")
    with pytest.raises(ConfigError, match="not empty"):
        check_output(tmp_path / "mine", "--out", kind="dir")
    with pytest.raises(ConfigError, match="not made by edgepick bench"):
        check_output(tmp_path / "mine", "--out", kind="dir", reuse="bench")
    with output_dir(tmp_path / "tables", "bench") as out:
        (out / "table.md").write_text("|")
    assert made_by(tmp_path / "tables") == "bench"
    check_output(tmp_path / "tables", "--out", kind="dir", reuse="bench")
    with pytest.raises(ConfigError, match="not made by edgepick demo"):
        check_output(tmp_path / "tables", "--workdir", kind="dir", reuse="demo")


def test_output_dir_removes_only_what_it_made_when_the_work_fails(tmp_path):
    with pytest.raises(KeyboardInterrupt):
        with output_dir(tmp_path / "a" / "b" / "out", "bench") as out:
            (out / "half.md").write_text("half")
            raise KeyboardInterrupt
    assert list(tmp_path.iterdir()) == []  # the folder and the parents made for it
    (tmp_path / "empty").mkdir()
    with pytest.raises(RuntimeError):
        with output_dir(tmp_path / "empty", "bench") as out:
            (out / "half.md").write_text("half")
            raise RuntimeError
    assert list((tmp_path / "empty").iterdir()) == []
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("the user's")
    with pytest.raises(ConfigError, match="not made by edgepick demo"):
        with output_dir(tmp_path / "mine", "demo", fresh=True):
            pass
    assert [p.name for p in (tmp_path / "mine").iterdir()] == ["notes.txt"]


def test_output_dir_fresh_empties_the_commands_own_folder_first(tmp_path):
    with output_dir(tmp_path / "demo", "demo", fresh=True) as out:
        (out / "old.json").write_text("{}")
    with output_dir(tmp_path / "demo", "demo", fresh=True) as out:
        assert sorted(p.name for p in out.iterdir()) == [".edgepick"]
        (out / "new.json").write_text("{}")
    assert sorted(p.name for p in (tmp_path / "demo").iterdir()) == [".edgepick", "new.json"]
