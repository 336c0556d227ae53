"""Writing outputs: checked before any work, written whole or not at all, never over what
edgepick did not make, with the user's umask.

The one rule for output paths in every command (docs/contracts.md#command-line), checked up
front by `check_output` before hours of training or seconds of calibration: missing parent
folders are created when the output is written; the nearest folder that exists must be
writable; an output is a regular file or a folder, never a link, device, FIFO or socket, never
inside /proc, /sys or /dev, never one of the command's inputs. Files and data set folders appear
under their final name only when complete (a temporary sibling, then `os.replace`), so an
interrupted or failed command leaves nothing half-written. A folder a command writes into
(`output_dir`) carries a MARKER naming that command; edgepick removes or reuses only such a
folder, or an empty one, never the working folder or a folder above it. Temporary files from
`tempfile` are private (0600/0700); what is renamed into place gets the permissions any other
tool would give it under the user's umask.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import shutil
import stat
import tempfile
from collections.abc import Iterator
from pathlib import Path

from edgepick.errors import ConfigError


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def public_mode(path: str | Path) -> None:
    """Give a file 0666 and a folder 0777 (minus the umask), as open() and mkdir() would."""
    path = Path(path)
    os.chmod(path, (0o777 if path.is_dir() else 0o666) & ~_umask())


SYSTEM_FOLDERS = ("/proc", "/sys", "/dev")  # kernel and device file systems: never an output
MARKER = ".edgepick"  # in a folder edgepick made: which command made it (made_by)
TEMP_ROOM = 24  # bytes a temporary sibling's name adds to an output's name (".NAME.partial-XXXXXXXX")


def _special(mode: int) -> str | None:
    """What a path that is neither a regular file nor a folder is, in words; None for those two."""
    for test, words in ((stat.S_ISLNK, "a symbolic link"), (stat.S_ISCHR, "a character device"),
                        (stat.S_ISBLK, "a block device"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
                        (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return words
    return None


def _lstat(path: str | Path, label: str = "") -> os.stat_result | None:
    try:
        return os.lstat(path)
    except (FileNotFoundError, NotADirectoryError):
        return None
    except OSError as exc:  # a loop or a name too long on the way
        raise ConfigError(f"{label or path}: {exc.strerror} (at {path})") from None


def _within(path: str, folder: str) -> bool:
    return path == folder or path.startswith(folder.rstrip(os.sep) + os.sep)


def made_by(folder: str | Path) -> str | None:
    """The edgepick command that made FOLDER (its MARKER file), or None."""
    try:
        found = json.loads((Path(folder) / MARKER).read_text()).get("made_by")
        return found if isinstance(found, str) else None
    except (OSError, ValueError, AttributeError):
        return None


def mark(folder: str | Path, command: str) -> None:
    """Say in FOLDER that edgepick COMMAND made it: later runs of that command may reuse or
    replace it, and nothing else."""
    from edgepick import __version__

    (Path(folder) / MARKER).write_text(json.dumps({"made_by": command, "edgepick": __version__}) + "\n")


def _check_names(path: Path, label: str, existing: Path) -> None:
    try:
        name_max = os.pathconf(existing, "PC_NAME_MAX")
        path_max = os.pathconf(existing, "PC_PATH_MAX")
    except (OSError, ValueError):
        name_max, path_max = 255, 4096
    for part in path.parts:
        if len(os.fsencode(part)) + TEMP_ROOM > name_max:
            raise ConfigError(f"{label}: the name {part[:24]}... is {len(os.fsencode(part))} bytes; this file "
                              f"system takes {name_max - TEMP_ROOM} at most")
    if len(os.fsencode(path.absolute())) + TEMP_ROOM > path_max:
        raise ConfigError(f"{label}: the path is longer than this system's limit of {path_max - TEMP_ROOM} bytes")


def _check_inputs(path: Path, label: str, kind: str, inputs: tuple) -> None:
    """An output may not be one of the command's inputs (or another of its outputs), overwrite a
    file inside an input folder, or be a folder that holds an input."""
    real = os.path.realpath(path)
    for given in inputs:
        if given is None or not os.fspath(given).strip():
            continue
        source = os.path.realpath(given)
        if real == source:
            raise ConfigError(f"{label} is the same path as {given}, an input or another output of this command; "
                              "write the output elsewhere")
        if kind == "file" and os.path.isdir(source) and _within(real, source) and os.path.lexists(path):
            raise ConfigError(f"{label} would overwrite a file of the input {given}; write the output elsewhere")
        if kind == "dir" and _within(source, real):
            raise ConfigError(f"{label} holds the input {given}; write the output elsewhere")


def check_output(path: str | Path, option: str = "out", kind: str = "file", suffixes: tuple[str, ...] = (),
                 inputs: tuple = (), reuse: str | None = None) -> Path:
    """Refuse an output path before any work starts (docs/contracts.md#command-line): an empty
    path; a suffix other than SUFFIXES; an existing path of the other kind (a folder where a file
    goes, or the reverse); a symbolic link, device, FIFO or socket; a path in a kernel or device
    file system; a name too long for the file system; a file where a parent folder should be; a
    nearest existing folder that is not writable; one of the command's INPUTS. A folder output
    must not be the working folder or hold it, and an existing one must be empty, or made by the
    edgepick command REUSE (its MARKER). OPTION names the output in messages (a command's flag)."""
    text = os.fspath(path)
    if not text.strip():
        raise ConfigError(f"{option} is empty; give a {'folder' if kind == 'dir' else 'file'} name")
    path = Path(text)
    label = f"{option} {text}"
    if suffixes and path.suffix.lower() not in suffixes:
        raise ConfigError(f"{label}: must end in {' or '.join(suffixes)}")
    parent = path.absolute().parent
    while _lstat(parent, label) is None:
        parent = parent.parent
    _check_names(path, label, parent if os.path.isdir(parent) else Path("/"))
    st = _lstat(path, label)
    if st is not None:
        if stat.S_ISLNK(st.st_mode):
            target = os.readlink(path)
            if not os.path.exists(path):
                raise ConfigError(f"{label} is a broken symbolic link (to {target})")
            raise ConfigError(f"{label} is a symbolic link (to {target}); give the path it points to")
        if _special(st.st_mode):
            raise ConfigError(f"{label} exists and is {_special(st.st_mode)}; edgepick writes only regular files "
                              "and folders")
        if kind == "file" and stat.S_ISDIR(st.st_mode):
            raise ConfigError(f"{label} is a folder; give a file name")
        if kind == "dir" and not stat.S_ISDIR(st.st_mode):
            raise ConfigError(f"{label} is a file; give a folder")
    if not os.path.exists(parent):
        raise ConfigError(f"{label}: {parent} is a broken symbolic link")
    if not os.path.isdir(parent):
        raise ConfigError(f"{label}: {parent} is a file, not a folder")
    real = os.path.realpath(path)
    system = next((s for s in SYSTEM_FOLDERS if _within(real, s)), None)
    if system:
        raise ConfigError(f"{label} is inside {system}, a kernel or device file system; write to a normal folder")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise ConfigError(f"{label}: cannot write in {parent} (permission denied)")
    if st is not None and not os.access(path, os.W_OK):
        raise ConfigError(f"{label}: cannot overwrite it (permission denied)")
    if kind == "dir":
        if _within(os.path.realpath(os.getcwd()), real):
            raise ConfigError(f"{label} is the working folder or holds it; give a new folder")
        if st is not None and any(Path(path).iterdir()) and (reuse is None or made_by(path) != reuse):
            own = f" and was not made by edgepick {reuse}" if reuse else ""
            raise ConfigError(f"{label} is not empty{own}; choose a new folder (edgepick replaces only what it made)")
    _check_inputs(path, label, kind, inputs)
    return path


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary sibling of PATH (same suffix, so writers that go by it still work);
    on success it replaces PATH with the user's permissions, on failure it is removed."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=f".tmp{path.suffix}", dir=path.parent)
    os.close(fd)
    try:
        yield Path(tmp)
        public_mode(tmp)
        st = _lstat(path)
        if st is not None and not stat.S_ISREG(st.st_mode):  # never rename over a device, FIFO, socket, link
            raise ConfigError(f"{path} is {_special(st.st_mode) or 'a folder'}; edgepick writes only regular files")
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def atomic_write(path: str | Path, data: str | bytes) -> Path:
    """Write DATA (text or bytes) to PATH whole or not at all."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data.encode() if isinstance(data, str) else data)
    return Path(path)


@contextlib.contextmanager
def atomic_dir(path: str | Path) -> Iterator[Path]:
    """Yield a temporary sibling folder of PATH; on success it becomes PATH, which must be new or
    an empty folder (nothing else is ever replaced); on failure it is removed with everything in it."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.partial-", dir=path.parent))
    try:
        yield tmp
        public_mode(tmp)
        if os.path.lexists(path) and not (path.is_dir() and not path.is_symlink() and not any(path.iterdir())):
            raise ConfigError(f"{path} already exists and is not an empty folder; edgepick does not replace it")
        os.replace(tmp, path)  # a rename over an empty folder
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def _clear(folder: Path, keep: tuple[str, ...] = ()) -> None:
    for entry in folder.iterdir():
        if entry.name in keep:
            continue
        if entry.is_dir() and not entry.is_symlink():
            shutil.rmtree(entry)
        else:
            entry.unlink()


@contextlib.contextmanager
def output_dir(path: str | Path, command: str, fresh: bool = False) -> Iterator[Path]:
    """A folder that COMMAND writes into (bench tables, pick overlays, the demo's work, a run):
    made and marked when missing; used when empty or made by COMMAND before (FRESH: its old
    contents removed first); any other folder is refused (check_output says so up front). If the
    block fails or is interrupted, a folder made here is removed with the parents made for it,
    and one that was empty (or FRESH) is emptied again."""
    path = Path(path)
    missing = path
    while not os.path.lexists(missing.parent) and missing.parent != missing:
        missing = missing.parent
    existed = os.path.lexists(path)
    if existed:
        if not path.is_dir() or path.is_symlink():
            raise ConfigError(f"{path} is not a folder")
        if any(path.iterdir()) and made_by(path) != command:
            raise ConfigError(f"{path} is not empty and was not made by edgepick {command}; choose a new folder")
        if _within(os.path.realpath(os.getcwd()), os.path.realpath(path)) and fresh:
            raise ConfigError(f"{path} is the working folder or holds it; give a new folder")
    empty_before = existed and not any(path.iterdir())
    if existed and fresh:
        _clear(path, keep=(MARKER,))
    path.mkdir(parents=True, exist_ok=True)
    mark(path, command)
    try:
        yield path
    except BaseException:
        if not existed:
            shutil.rmtree(path, ignore_errors=True)
            for parent in path.parents:  # the parents made for it, nearest first
                if parent == missing.parent:
                    break
                with contextlib.suppress(OSError):
                    parent.rmdir()
        elif empty_before or fresh:
            _clear(path, keep=() if empty_before else (MARKER,))
        raise


def sha256_of(path: str | Path) -> str:
    """The file's SHA-256, read in 1 MiB blocks."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()
