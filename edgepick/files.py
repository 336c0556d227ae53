"""Writing outputs: checked before any work, written whole or not at all, with the user's umask.

The one rule for output paths in every command (docs/contracts.md#command-line): missing
parent folders are created when the output is written; the nearest folder that exists must be
writable, and that is checked up front (`check_output`), before hours of training or seconds
of calibration. Files and data set folders appear under their final name only when complete
(a temporary sibling, then `os.replace`), so an interrupted or failed command leaves nothing
half-written. Temporary files from `tempfile` are private (0600/0700); what is renamed into
place gets the permissions any other tool would give it under the user's umask.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import shutil
import tempfile
from pathlib import Path
from typing import Iterator

from edgepick.errors import ConfigError


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def public_mode(path: str | Path) -> None:
    """Give a file 0666 and a folder 0777 (minus the umask), as open() and mkdir() would."""
    path = Path(path)
    os.chmod(path, (0o777 if path.is_dir() else 0o666) & ~_umask())


def check_output(path: str | Path, option: str = "--out", kind: str = "file", suffixes: tuple[str, ...] = ()) -> Path:
    """Refuse an output path before any work starts: an existing path of the other kind (a
    folder where a file goes, or the reverse), a suffix other than `suffixes`, a file where a
    parent folder should be, or a nearest existing folder that is not writable."""
    path = Path(path)
    if suffixes and path.suffix.lower() not in suffixes:
        raise ConfigError(f"{option} {path}: must end in {' or '.join(suffixes)}")
    if kind == "file" and path.is_dir():
        raise ConfigError(f"{option} {path} is a folder; give a file name")
    if kind == "dir" and path.exists() and not path.is_dir():
        raise ConfigError(f"{option} {path} is a file; give a folder")
    parent = path.absolute().parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise ConfigError(f"{option} {path}: {parent} is a file, not a folder")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise ConfigError(f"{option} {path}: cannot write in {parent} (permission denied)")
    if path.exists() and not os.access(path, os.W_OK):
        raise ConfigError(f"{option} {path}: cannot overwrite it (permission denied)")
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
    """Yield a temporary sibling folder of PATH; on success it becomes PATH (an existing PATH
    is replaced only then), on failure it is removed with everything in it."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.partial-", dir=path.parent))
    try:
        yield tmp
        public_mode(tmp)
        if path.exists():
            shutil.rmtree(path)
        os.replace(tmp, path)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def sha256_of(path: str | Path) -> str:
    """The file's SHA-256, read in 1 MiB blocks."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()
