"""A campaign's rows on disk: ``parts/part-*.parquet`` while it runs, ``flights.parquet`` once merged.

Every file is written whole to a temporary file, flushed and renamed over its name (``radseek_io.outdir.atomic_path``):
a kill -9 or a crash leaves the previous file or the new one, never half of one. Pages carry CRC checksums and the
merged file is cut into row groups of ``ROW_GROUP_ROWS`` rows, so damage done to a file afterwards (a disk error, a
bad copy, a truncation) is detected when it is read and costs only the row groups it hit.

A damaged file is never read past, overwritten or deleted: :func:`load_rows` raises :class:`DamagedStore` naming the
file, what is wrong and how many of its rows are still readable; with ``salvage`` it keeps those rows (written as a
new part file), moves the file aside (``NAME.damaged``) and lets the campaign fly the lost flights again.
"""

from __future__ import annotations

import json
import os
import shutil
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from radseek_io.outdir import atomic_path

__all__ = ["FLUSH_ROWS", "FLUSH_S", "ROW_GROUP_ROWS", "DamagedFile", "DamagedStore", "PartWriter", "load_rows",
           "merge", "params_of", "read_file", "salvage", "write_rows"]

FLUSH_ROWS = 25  # rows buffered before a part file is written
FLUSH_S = 30.0  # s: ... or this long after the last part file
ROW_GROUP_ROWS = 32  # rows per row group of the merged file: what one damaged spot can cost
PARTS = "parts"
MERGED = "flights.parquet"


@dataclass
class DamagedFile:
    """A row file that cannot be read whole: what is wrong, and the rows of its readable row groups."""

    path: Path
    problem: str
    rows: list[dict[str, Any]]
    total_rows: int | None  # from the file's footer; None when the footer is unreadable

    def readable(self) -> str:
        """``"90 of 100 rows"`` / ``"no rows"``: what is left of the file."""
        if self.total_rows is None:
            return f"{len(self.rows)} rows" if self.rows else "no rows"
        return f"{len(self.rows)} of {self.total_rows} rows"


class DamagedStore(Exception):
    """The campaign's recorded rows include a damaged file (one line: the file, what is wrong, what to do)."""

    def __init__(self, damaged: list[DamagedFile]):
        self.damaged = damaged
        first = damaged[0]
        more = f" (and {len(damaged) - 1} more damaged files)" if len(damaged) > 1 else ""
        keep = f"keep the {len(first.rows)} readable rows, " if first.rows else ""
        super().__init__(f"{first.path} is damaged ({first.problem}); {first.readable()} readable{more}. Nothing was "
                         f"changed: rerun with --salvage to {keep}move it aside to {_aside(first.path).name} and fly "
                         f"its{' other' if first.rows else ''} flights again, or restore it from a backup")


def params_of(row: Mapping[str, Any]) -> dict[str, Any]:
    """The swept parameters of a row (its ``p.<name>`` columns)."""
    return {k: row[k] for k in row if k.startswith("p.")}


def _table(rows: list[dict[str, Any]]):
    import pyarrow as pa

    columns: dict[str, None] = {}
    for r in rows:
        columns.update(dict.fromkeys(r))
    return pa.Table.from_pylist([{c: r.get(c) for c in columns} for r in rows])


def write_rows(path: Path, rows: list[dict[str, Any]]) -> None:
    """``rows`` as a Parquet file at ``path``, atomically, with page checksums and small row groups."""
    import pyarrow.parquet as pq

    with atomic_path(path) as tmp:
        pq.write_table(_table(rows), tmp, row_group_size=ROW_GROUP_ROWS, write_page_checksum=True)


def _problem(exc: Exception, size: int) -> str:
    text = " ".join(str(exc).split())
    if size == 0:
        return "empty: 0 bytes"
    if "magic bytes not found" in text:
        return f"truncated or not a Parquet file: no Parquet footer in its {size} bytes"
    return f"unreadable footer: {text[:160]}"


def read_file(path: Path) -> list[dict[str, Any]] | DamagedFile:
    """The rows of one row file, or what is wrong with it and the rows still readable (row group by row group,
    page checksums verified)."""
    import pyarrow.parquet as pq

    try:
        size = path.stat().st_size
        f = pq.ParquetFile(path, page_checksum_verification=True)
    except OSError as exc:
        if exc.errno is not None:  # cannot open it at all (permissions, I/O error): not a damaged file
            raise
        return DamagedFile(path, _problem(exc, size), [], None)
    except Exception as exc:  # noqa: BLE001 - pyarrow raises ArrowInvalid and others for a bad footer
        return DamagedFile(path, _problem(exc, size), [], None)
    rows: list[dict[str, Any]] = []
    bad: list[tuple[int, str]] = []
    for i in range(f.num_row_groups):
        try:
            rows += f.read_row_group(i).to_pylist()
        except Exception as exc:  # noqa: BLE001 - OSError (thrift, checksum), ArrowInvalid (decoding)
            bad.append((i, " ".join(str(exc).split())[:160]))
    if not bad and rows and "key" not in rows[0]:
        return DamagedFile(path, "not a campaign's rows: no 'key' column", [], f.metadata.num_rows)
    if bad:
        groups = ", ".join(str(i + 1) for i, _ in bad[:5]) + (", ..." if len(bad) > 5 else "")
        return DamagedFile(path, f"corrupted bytes in row group {groups} of {f.num_row_groups}: {bad[0][1]}", rows,
                           f.metadata.num_rows)
    return rows


def _files(out: Path) -> list[Path]:
    files = [out / MERGED] if (out / MERGED).exists() else []
    return files + (sorted((out / PARTS).glob("part-*.parquet")) if (out / PARTS).is_dir() else [])


def _aside(path: Path) -> Path:
    """Where a damaged file goes: ``flights.parquet.damaged`` (``.damaged-2``, ... if taken) in the campaign folder
    (a part file too: the parts folder is removed after a merge)."""
    folder = path.parent.parent if path.parent.name == PARTS else path.parent
    target, n = folder / f"{path.name}.damaged", 1
    while target.exists():
        n += 1
        target = folder / f"{path.name}.damaged-{n}"
    return target


def salvage(out: Path, damaged: DamagedFile) -> Path:
    """Keep ``damaged``'s readable rows as a new part file, then move the file aside; returns where it went.
    The rows are written first: a crash in between leaves them twice (the latest row of a key wins), never lost."""
    if damaged.rows:
        (out / PARTS).mkdir(parents=True, exist_ok=True)
        write_rows(out / PARTS / f"part-{time.time_ns():020d}-{os.getpid()}-salvaged.parquet", damaged.rows)
    target = _aside(damaged.path)
    os.replace(damaged.path, target)
    return target


def load_rows(out: str | Path) -> list[dict[str, Any]]:
    """Every recorded row of the campaign in ``out`` (merged file and unmerged parts), one per flight key (the latest
    wins). A damaged file raises :class:`DamagedStore` (nothing changed; :func:`salvage` each file to go on)."""
    out = Path(out)
    rows: dict[str, dict[str, Any]] = {}
    damaged: list[DamagedFile] = []
    for f in _files(out):
        got = read_file(f)
        if isinstance(got, DamagedFile):
            damaged.append(got)
            got = got.rows
        for row in got:
            rows[row["key"]] = row
    if damaged:
        raise DamagedStore(damaged)
    return list(rows.values())


class PartWriter:
    """Rows as they come in, written as part files every ``FLUSH_ROWS`` rows or ``FLUSH_S`` seconds."""

    def __init__(self, out: Path):
        self.dir = out / PARTS
        self.dir.mkdir(parents=True, exist_ok=True)
        self.buffer: list[dict[str, Any]] = []
        self.last = time.monotonic()
        self.n = 0

    def add(self, row: dict[str, Any]) -> None:
        self.buffer.append(row)
        if len(self.buffer) >= FLUSH_ROWS or time.monotonic() - self.last > FLUSH_S:
            self.flush()

    def flush(self) -> None:
        self.last = time.monotonic()
        if not self.buffer:
            return
        self.n += 1
        write_rows(self.dir / f"part-{time.time_ns():020d}-{os.getpid()}-{self.n:05d}.parquet", self.buffer)
        self.buffer = []


def _canonical(obj: Any) -> str:
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), default=str)


def merge(out: Path) -> list[dict[str, Any]]:
    """Merge parts into ``flights.parquet`` (atomically, then drop the parts); returns the rows."""
    rows = load_rows(out)
    rows.sort(key=lambda r: (r["scene"], r["strategy"], r["effect"], _canonical(params_of(r)), r["seed"]))
    if rows:
        write_rows(out / MERGED, rows)
    shutil.rmtree(out / PARTS, ignore_errors=True)
    return rows
