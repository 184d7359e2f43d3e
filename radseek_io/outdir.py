"""Output folders and atomic writes: a recorded flight is never overwritten or mixed up with another.

- ``prepare_output(path, force=..., outputs=...)``: the folder a command writes into. A non-empty
  folder is refused (``OutputDirError`` naming the folder and ``--force``) unless ``force``; with
  ``force`` the command's own previous ``outputs`` are removed first — summaries and reports before
  data — so an aborted run can never leave an old summary beside new partial frames. Other files in
  the folder are left alone: ``--force`` never deletes what radseek did not write.
- ``check_output_file(path, force=...)``: the same rule for a command that writes one file: an existing file is
  refused unless ``force``.
- ``atomic_write_text`` / ``atomic_write_bytes`` / ``atomic_write_json`` / ``atomic_path``: write to
  a temporary file in the same folder, flush it to disk, then ``os.replace`` it over the target, so a
  reader (or a crash) sees the old file or the new one, never half of one.
- ``file_problem(exc)``: a failed file operation in one line, the file named (``radseek`` prints it for any command).
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import shutil
import tempfile
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

TMP_PREFIX = ".tmp-"


def file_problem(exc: OSError) -> str:
    """``FILE: the system's words (ERRNO)`` for a failed file operation: ``.../plot.png: Not a directory (ENOTDIR)``;
    ``.../f: File exists (EEXIST), not a folder`` where a file holds the name of a folder to be made."""
    where = f"{exc.filename}" + (f" -> {exc.filename2}" if exc.filename2 else "")
    name = errno.errorcode.get(exc.errno or 0, "")
    line = f"{where}: {exc.strerror or exc}{f' ({name})' if name else ''}"
    if isinstance(exc, FileExistsError) and exc.filename and not Path(exc.filename).is_dir():
        line += ", not a folder"
    return line


class OutputDirError(Exception):
    """An output folder that cannot be used as asked (names the folder and the way out)."""


def prepare_output(path: str | Path, *, force: bool, outputs: Iterable[str], flag: str = "--force") -> Path:
    """Create ``path`` or check it is empty; with ``force`` remove the previous ``outputs`` in it (in
    the order given: list summaries first). Returns the folder."""
    path = Path(path)
    try:
        return _prepare(path, force, outputs, flag)
    except OSError as exc:  # a parent that is a file, no permission, a read-only or full disk
        raise OutputDirError(f"output folder {path} cannot be created or cleared: "
                             f"{exc.strerror or exc}{f' ({exc.filename})' if exc.filename else ''}") from None


def _prepare(path: Path, force: bool, outputs: Iterable[str], flag: str) -> Path:
    if path.exists() and not path.is_dir():
        raise OutputDirError(f"output folder {path} exists and is not a folder")
    if path.is_dir():
        entries = sorted(p.name for p in path.iterdir())
        if entries and not force:
            shown = ", ".join(entries[:5]) + (", ..." if len(entries) > 5 else "")
            raise OutputDirError(f"output folder {path} is not empty ({shown}): it may hold a recorded flight; "
                                 f"choose another --out or pass {flag} to replace its previous outputs")
        if force:
            for name in outputs:
                _remove(path / name)
            for stale in path.glob(f"{TMP_PREFIX}*"):  # half-written temporaries of an aborted run
                _remove(stale)
    path.mkdir(parents=True, exist_ok=True)
    return path


def check_output_file(path: str | Path, *, force: bool, flag: str = "--force") -> Path:
    """A single file a command writes (``radseek calibrate --out DET.json``): refused when it exists, unless
    ``force`` (``OutputDirError`` naming the file and ``flag``), and when its folder does not exist or the path is a
    folder. Call it before the work, write with ``atomic_write_*`` after: a refused run costs nothing and a forced
    one replaces the old file only once the new one is complete."""
    path = Path(path)
    if path.is_dir():
        raise OutputDirError(f"output file {path} is a folder; give a file name")
    if not path.parent.is_dir():
        raise OutputDirError(f"output file {path}: folder {path.parent} does not exist")
    if (path.exists() or path.is_symlink()) and not force:
        raise OutputDirError(f"output file {path} exists: it may hold an earlier result; choose another --out or "
                             f"pass {flag} to replace it")
    return path


def _remove(p: Path) -> None:
    if p.is_dir() and not p.is_symlink():
        shutil.rmtree(p)
    elif p.exists() or p.is_symlink():
        p.unlink()


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """A temporary path in ``path``'s folder to write to; on success it replaces ``path`` atomically,
    on error it is removed and ``path`` is untouched."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f"{TMP_PREFIX}{path.name}.")
    os.close(fd)
    tmp_path = Path(tmp)
    os.chmod(tmp_path, 0o644)  # mkstemp makes it private; the result is an ordinary output file
    try:
        yield tmp_path
        with open(tmp_path, "rb+") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp_path, path)
        _fsync_folder(path.parent)
    finally:
        tmp_path.unlink(missing_ok=True)


def _fsync_folder(folder: Path) -> None:
    """Make a rename in ``folder`` durable (a power cut after it keeps the new name); best effort."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def atomic_write_text(path: str | Path, text: str) -> None:
    atomic_write_bytes(path, text.encode())


def atomic_write_json(path: str | Path, data: Any, **dumps: Any) -> None:
    """``data`` as indented JSON (``default=float`` unless given) plus a newline, atomically."""
    dumps.setdefault("indent", 2)
    dumps.setdefault("default", float)
    atomic_write_text(path, json.dumps(data, **dumps) + "\n")
