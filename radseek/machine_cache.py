"""This machine's cache of values read from a library's data files (pydecay's RAD rows, xraydb's cross-sections):
a process that loads a scene or a detector response would otherwise parse whole tables, or import a database
layer, for a handful of values, every time it starts.

Each cache lives in a folder or file named by a key that includes the library's version and its data file's
path, size and modification time, so a new library or a changed table is another cache. Files are JSON, written
atomically (a temporary file replaced into place); any OSError or unreadable content is a miss, and the caller
computes the value from the library as it would without a cache. Nothing is typed here: every value is the
library's own, read through its API the first time it is asked for.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

#: the cache folder: $RADSEEK_CACHE_DIR, else $XDG_CACHE_HOME/radseek, else ~/.cache/radseek
CACHE_ENV = "RADSEEK_CACHE_DIR"


def cache_root() -> Path:
    root = os.environ.get(CACHE_ENV) or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache"), "radseek")
    return Path(root)


def package_version(package: str) -> str:
    """The installed version of ``package`` (its distribution's metadata: no import), "?" when unknown."""
    import importlib.metadata

    try:
        return importlib.metadata.version(package)
    except importlib.metadata.PackageNotFoundError:
        return "?"


def package_file(package: str, *parts: str) -> Path | None:
    """The file ``parts`` inside the installed package ``package``, found without importing it; None when the
    package is not installed."""
    import importlib.util

    spec = importlib.util.find_spec(package)
    if spec is None or not spec.submodule_search_locations:
        return None
    return Path(next(iter(spec.submodule_search_locations))).joinpath(*parts)


def keyed_path(kind: str, version: str, data_file: Path | Sequence[Path] | None, suffix: str = "") -> Path | None:
    """``ROOT/KIND-HASH[SUFFIX]``, HASH of the library's version and its data file's (or files') path, size and
    modification time; None when a data file is unknown or cannot be stat'ed."""
    files = [data_file] if data_file is None or isinstance(data_file, Path) else list(data_file)
    stamps: list[Any] = []
    for f in files:
        if f is None:
            return None
        try:
            st = f.stat()
        except OSError:
            return None
        stamps += [str(f), st.st_size, st.st_mtime_ns]
    key = json.dumps([version, *stamps])
    return cache_root() / f"{kind}-{hashlib.sha256(key.encode()).hexdigest()[:16]}{suffix}"


def read_json(path: Path | None) -> Any:
    """The JSON value cached at ``path``; None when there is none, or none readable."""
    if path is None:
        return None
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


def write_json(path: Path | None, value: Any) -> None:
    """Cache ``value`` at ``path``, atomically; an OSError leaves the cache as it was."""
    if path is None:
        return
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}", suffix=".tmp")
        try:
            with os.fdopen(fd, "w", encoding="utf-8") as fh:
                json.dump(value, fh)
            os.replace(tmp, path)
        except BaseException:
            os.unlink(tmp)
            raise
    except OSError:
        return
