"""The ``radseek-dataset/1`` format (shared/spec/dataset-format.md): read, validate, write.

A dataset is a directory with ``frames.csv``, ``scenario.json`` and optionally ``truth.json``. It is
the seam between flying and analysing: every flight writes one, and ``localize``, ``diagnose``,
``compare`` and ``replay`` read one. Readers accept every file written to the contract and ignore
unknown columns and keys; errors name the file, row and column.

The types (``Frames``, ``Scenario``, ``Dataset``) are the contracts' (:mod:`radseek.dataset`).
:func:`read_dataset` reads the frames and the scenario only, never ``truth.json``: the truth has its own
reader (:mod:`radseek_io.truth`), which the flight software never imports.
"""

from __future__ import annotations

import csv
import errno
import io
import json
import math
import os
import re
import sys
import time
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from radseek.dataset import FORMAT, Dataset, DatasetError, Frames, Scenario, Wall
from radseek.frame_record import CHANNEL_COLUMNS, COLUMNS, COUNT_DTYPE, POSE_COLUMNS, FrameRecord
from radseek.topics import N_CHANNELS

if TYPE_CHECKING:
    from radseek.truth import Truth

# ---------------------------------------------------------------------------------------- reading

#: ``format`` values this reader understands: radseek-dataset/1 and its minor revisions (1.1, ...), not /10
_FORMAT_RE = re.compile(r"radseek-dataset/1(?:\.\d+)*")
#: Largest extent (m) of the source bounds on any axis, and largest |coordinate| of bounds and walls. A small
#: drone searches at most a few hundred metres; anything beyond is a units error (mm, degrees), and
#: +-1e6 m bounds make grid-based estimators and planners run without limit.
MAX_EXTENT_M = 2000.0
#: walls a scene or scenario may hold (a room's walls are tens; 10^6 walls made a 1.5 s-of-sim-per-28 s flight)
MAX_WALLS = 1000
#: sources a scene may hold
MAX_SOURCES = 16
#: the largest air attenuation coefficient scenario.json may declare (1/m): dense gas at 100x dry air's 0.0093
MAX_AIR_MU_PER_M = 1.0
MAX_COORD_M = 10_000.0
#: Largest count of one channel in one frame: the board's u16 field is 65535 per 0.1 s frame; this leaves
#: room for other hardware and longer frames, and keeps sums over a million frames inside int64.
MAX_COUNT = 1_000_000_000
#: Largest dwell index (int32: nothing flies a billion dwells)
MAX_DWELL = 2**31 - 1
#: Bytes per block of the streaming CSV reader, and the file size from which reads report progress
_BLOCK_BYTES = 8 << 20


class DatasetWarning(UserWarning):
    """A dataset that was read with a repair the caller should know about (e.g. a truncated last row skipped)."""


def _err(file: Path, msg: str) -> DatasetError:
    return DatasetError(f"{file}: {msg}")


def _is_number(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


def _number(v: Any, where: str, file: Path) -> float:
    """A finite JSON number (not a bool, string or NaN) as float; DatasetError naming ``where`` otherwise."""
    if not _is_number(v):
        raise _err(file, f"key {where!r} must be a number, got {v!r}")
    try:
        f = float(v)
    except OverflowError:  # an integer literal beyond float range
        raise _err(file, f"key {where!r} is out of range, got {v!r}") from None
    if not math.isfinite(f):
        raise _err(file, f"key {where!r} must be finite, got {v!r}")
    return f


def _get(d: dict, keypath: str, file: Path, kind: type | tuple = (int, float)) -> Any:
    cur: Any = d
    for part in keypath.split("."):
        if not isinstance(cur, dict) or part not in cur:
            raise _err(file, f"missing key {keypath!r}")
        cur = cur[part]
    if kind in ((int, float), float):
        return _number(cur, keypath, file)
    return cur


def _vector(d: dict, keypath: str, file: Path, n: int) -> np.ndarray:
    v = _get(d, keypath, file, kind=list)
    if not isinstance(v, list) or len(v) != n:
        raise _err(file, f"key {keypath!r} must be a list of {n} numbers, got {v!r}")
    return np.array([_number(a, f"{keypath}[{i}]", file) for i, a in enumerate(v)], dtype=float)


def _load_json(file: Path, required: bool) -> Any:
    """Parsed JSON of ``file`` (a UTF-8 BOM is allowed); None when it is missing and not required."""
    try:
        raw = file.read_bytes()
    except FileNotFoundError:
        if not required:
            return None
        raise _err(file, "file is missing (a dataset needs frames.csv and scenario.json)") from None
    except OSError as exc:
        raise _err(file, f"cannot be read: {exc.strerror or exc}") from None
    try:
        return json.loads(raw.decode("utf-8-sig"))
    except UnicodeDecodeError as exc:
        raise _err(file, f"not UTF-8 text (byte {exc.start})") from None
    except json.JSONDecodeError as exc:
        raise _err(file, f"not valid JSON: {exc}") from None
    except RecursionError:
        raise _err(file, "not valid JSON: nested too deeply") from None


def _check_point(p: np.ndarray, where: str, file: Path) -> None:
    if np.any(np.abs(p) > MAX_COORD_M):
        raise _err(file, f"key {where!r}: coordinates beyond +-{MAX_COORD_M:g} m of the local origin, got "
                         f"{p.tolist()} (metres expected)")


def check_bounds(bmin: np.ndarray, bmax: np.ndarray, file: Path) -> None:
    """The source bounds a dataset may hold: max >= min, within MAX_COORD_M of the origin, at most MAX_EXTENT_M
    per axis (read and write both check them)."""
    if np.any(bmax < bmin):
        raise _err(file, "key 'bounds': max must be >= min on every axis")
    _check_point(bmin, "bounds.min", file)
    _check_point(bmax, "bounds.max", file)
    if np.any(bmax - bmin > MAX_EXTENT_M):
        span = " x ".join(f"{v:.0f}" for v in bmax - bmin)
        raise _err(file, f"key 'bounds' spans {span} m; at most {MAX_EXTENT_M:g} m per axis (metres expected)")


def _read_wall(w: Any, where: str, file: Path) -> Wall:
    if not isinstance(w, dict):
        raise _err(file, f"{where} must be an object, got {w!r}")
    pts = []
    for key in ("start", "end"):
        if key not in w:
            raise _err(file, f"{where}: missing key {key!r}")
        v = w[key]
        if not isinstance(v, list) or len(v) != 2:
            raise _err(file, f"key '{where}.{key}' must be [x, y], got {v!r}")
        p = np.array([_number(a, f"{where}.{key}[{i}]", file) for i, a in enumerate(v)])
        _check_point(p, f"{where}.{key}", file)
        pts.append(p)
    if "thickness" not in w:
        raise _err(file, f"{where}: missing key 'thickness'")
    thickness = _number(w["thickness"], f"{where}.thickness", file)
    height = _number(w.get("height", 3.0), f"{where}.height", file)
    for key, value in (("thickness", thickness), ("height", height)):
        if value <= 0:  # a slab without volume: no path length through it, an attenuation with nothing to fit
            raise _err(file, f"key '{where}.{key}' must be > 0 (metres), got {w.get(key, value)!r}")
    length = float(np.hypot(*(pts[1] - pts[0])))
    if length == 0:
        raise _err(file, f"{where}: start and end are the same point {pts[0].tolist()} (a zero-length wall)")
    start = (float(pts[0][0]), float(pts[0][1]))
    end = (float(pts[1][0]), float(pts[1][1]))
    return Wall(start, end, thickness, height, str(w.get("material", "concrete")))


def read_scenario(file: Path) -> Scenario:
    """Read and validate scenario.json: types, finiteness, ranges and geometry; errors name the key."""
    file = Path(file)
    d = _load_json(file, required=True)
    if not isinstance(d, dict):
        raise _err(file, f"must hold a JSON object, got {type(d).__name__}")
    fmt = d.get("format", FORMAT)
    if not isinstance(fmt, str) or not _FORMAT_RE.fullmatch(fmt):
        raise _err(file, f"key 'format' is {fmt!r}; this reader understands {FORMAT}")
    detector = _get(d, "detector", file, kind=dict)
    if not isinstance(detector, dict):
        raise _err(file, f"key 'detector' must be an object, got {detector!r}")
    edges_raw = _get(d, "detector.channel_edges_keV", file, kind=list)
    if not isinstance(edges_raw, list) or len(edges_raw) != N_CHANNELS + 1:
        raise _err(file, f"key 'detector.channel_edges_keV' must list {N_CHANNELS + 1} numbers")
    edges = np.array([_number(e, f"detector.channel_edges_keV[{i}]", file) for i, e in enumerate(edges_raw)])
    if not np.all(np.diff(edges) > 0):
        raise _err(file, "key 'detector.channel_edges_keV' must be strictly ascending")
    background = _get(d, "background_cps", file)
    if background < 0:
        raise _err(file, f"key 'background_cps' must be >= 0, got {background}")
    source_z = _number(d["source_z"], "source_z", file) if "source_z" in d else 0.0
    bmin = _vector(d, "bounds.min", file, 3)
    bmax = _vector(d, "bounds.max", file, 3)
    check_bounds(bmin, bmax, file)
    walls_raw = d.get("walls", []) or []
    if not isinstance(walls_raw, list):
        raise _err(file, f"key 'walls' must be a list, got {walls_raw!r}")
    if len(walls_raw) > MAX_WALLS:
        raise _err(file, f"key 'walls' holds {len(walls_raw)} walls; at most {MAX_WALLS}")
    walls = [_read_wall(w, f"walls[{i}]", file) for i, w in enumerate(walls_raw)]
    for key in ("nuclide",):
        if key in d and not isinstance(d[key], str):
            raise _err(file, f"key {key!r} must be a string, got {d[key]!r}")
    axis = detector.get("axis", "body +x")
    if not isinstance(axis, str):
        raise _err(file, f"key 'detector.axis' must be a string, got {axis!r}")
    air = _number(d["air_mu_per_m"], "air_mu_per_m", file) if "air_mu_per_m" in d else 0.0
    if not 0 <= air <= MAX_AIR_MU_PER_M:
        raise _err(file, f"key 'air_mu_per_m' must be in [0, {MAX_AIR_MU_PER_M:g}] 1/m (air is ~0.01), got {air}")
    known = {"format", "nuclide", "detector", "background_cps", "source_z", "bounds", "walls", "air_mu_per_m"}
    return Scenario(
        channel_edges_keV=edges,
        background_cps=background,
        source_z=source_z,
        bounds_min=bmin,
        bounds_max=bmax,
        walls=tuple(walls),
        nuclide=str(d.get("nuclide", "Cs-137")),
        axis=axis,
        air_mu_per_m=air,
        extra={k: v for k, v in d.items() if k not in known},
    )


#: Overlapping walls. Every model sums the path length through each wall, so a region inside two walls attenuates
#: twice. Where walls meet (a corner or T-joint with centre lines sharing a point, a crossing) the slabs share a
#: patch of about t1 x t2 (the shipped outdoor scene's corners share 0.0056 m^2); that is how maps are drawn and is
#: accepted up to what two walls crossing at ``JOINT_MIN_ANGLE_DEG`` share, t1 t2 / sin(angle). More than that is
#: walls lying along each other (one listed twice, collinear segments overlapping, a shallow crossing), where the
#: doubled path runs along the wall. ``OVERLAP_TOLERANCE_M2`` absorbs rounding (lattice-wall's walls touch).
JOINT_MIN_ANGLE_DEG = 45.0
OVERLAP_TOLERANCE_M2 = 1e-4


def wall_footprint(wall: Wall) -> np.ndarray:
    """(4, 2) corners of the wall's footprint (the segment +- thickness/2), counter-clockwise."""
    a, b = np.asarray(wall.start, dtype=float), np.asarray(wall.end, dtype=float)
    length = float(np.hypot(*(b - a)))
    u = (b - a) / length if length > 0 else np.zeros(2)  # a zero-length wall: four equal corners
    n = np.array([-u[1], u[0]]) * wall.thickness / 2
    return np.array([a - n, b - n, b + n, a + n])


def _clip_convex(subject: list[np.ndarray], clip: np.ndarray) -> list[np.ndarray]:
    """Sutherland-Hodgman: the part of convex polygon ``subject`` inside convex counter-clockwise ``clip``."""
    out = subject
    for k in range(len(clip)):
        p, edge = clip[k], clip[(k + 1) % len(clip)] - clip[k]
        poly, out = out, []
        for m, cur in enumerate(poly):
            prev = poly[m - 1]
            s_cur = edge[0] * (cur[1] - p[1]) - edge[1] * (cur[0] - p[0])
            s_prev = edge[0] * (prev[1] - p[1]) - edge[1] * (prev[0] - p[0])
            if (s_cur >= 0) != (s_prev >= 0):
                out.append(prev + (cur - prev) * (s_prev / (s_prev - s_cur)))
            if s_cur >= 0:
                out.append(cur)
        if not out:
            break
    return out


def _area(poly: list[np.ndarray]) -> float:
    if len(poly) < 3:
        return 0.0
    x, y = np.array([p[0] for p in poly]), np.array([p[1] for p in poly])
    return 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))


def wall_overlaps(walls: Sequence[Wall]) -> list[tuple[int, int, float, float]]:
    """Pairs of walls whose footprints share more than a joint: ``(i, j, area_m2, allowed_m2)`` with i < j.

    ``area_m2`` is the exact area the two footprints share; ``allowed_m2`` what a joint of the two may share
    (t_i t_j / sin ``JOINT_MIN_ANGLE_DEG`` + ``OVERLAP_TOLERANCE_M2``). Touching walls share nothing."""
    feet = [wall_footprint(w) for w in walls]
    lo = [f.min(axis=0) for f in feet]
    hi = [f.max(axis=0) for f in feet]
    # a wall without length or thickness has no volume (and geometry.path_lengths gives it none)
    solid = [w.thickness > 0 and w.start != w.end for w in walls]
    out = []
    for i in range(len(walls)):
        for j in range(i + 1, len(walls)):
            if not (solid[i] and solid[j]) or np.any(lo[i] >= hi[j]) or np.any(lo[j] >= hi[i]):
                continue
            area = _area(_clip_convex(list(feet[i]), feet[j]))
            allowed = (walls[i].thickness * walls[j].thickness / math.sin(math.radians(JOINT_MIN_ANGLE_DEG))
                       + OVERLAP_TOLERANCE_M2)
            if area > allowed:
                out.append((i, j, area, allowed))
    return out


def check_walls_disjoint(scenario: Scenario, file: Path) -> None:
    """DatasetError naming the first two walls of ``scenario`` (read from ``file``) that overlap by more than a
    joint (``wall_overlaps``). Not part of ``read_scenario``: the format does not forbid it and a planner, which
    treats walls as obstacles, is not misled by it; commands that attenuate through walls call this."""
    overlaps = wall_overlaps(scenario.walls)
    if overlaps:
        i, j, area, allowed = overlaps[0]
        more = f" (and {len(overlaps) - 1} more pairs)" if len(overlaps) > 1 else ""
        raise _err(Path(file), f"key 'walls': walls[{i}] and walls[{j}] overlap by {area:.3g} m^2{more}, more "
                               f"than the {allowed:.2g} m^2 a joint of the two shares: paths through the overlap "
                               "would be attenuated twice; trim or merge the walls")


# ---- frames.csv

_FLOAT_COLUMNS = [c for c in POSE_COLUMNS if c != "dwell"]
#: the board's columns the recorder adds to frames.csv: read when present (``Frames.seq``, ``Frames.flags``),
#: with their defaults (-1: not known; 0) when not, and their largest value (u32 sequence, u8 flags)
BOARD_COLUMNS = {"seq": (-1, 2**32 - 1), "flags": (0, 255)}


def _board_error(values: np.ndarray, column: str) -> int | None:
    """Index of the first cell of board column ``column`` that is not a whole number in its range, else None."""
    hi = BOARD_COLUMNS[column][1]
    bad = ~np.isfinite(values) | (values < 0) | (values > hi) | (values != np.floor(values))
    return int(np.argmax(bad)) if bad.any() else None


class _Sink:
    """Preallocated columns filled block by block (capacity: the file's line count, an upper bound)."""

    def __init__(self, capacity: int):
        self.cols = {c: np.empty(capacity) for c in _FLOAT_COLUMNS}
        self.board = {c: np.full(capacity, default, dtype=np.int64) for c, (default, _) in BOARD_COLUMNS.items()}
        self.dwell = np.empty(capacity, dtype=np.int64)
        self.counts = np.empty((capacity, N_CHANNELS), dtype=COUNT_DTYPE)
        self.n = 0
        self.last_t = -math.inf

    def reserve(self, n: int) -> None:
        """Room for ``n`` more rows (the line count is an upper bound unless lines end in a bare CR)."""
        need = self.n + n
        if need <= len(self.dwell):
            return
        cap = max(need, 2 * len(self.dwell))
        self.cols = {c: np.resize(v, cap) for c, v in self.cols.items()}
        self.board = {c: np.r_[v, np.full(cap - len(v), BOARD_COLUMNS[c][0], dtype=np.int64)]
                      for c, v in self.board.items()}
        self.dwell = np.resize(self.dwell, cap)
        self.counts = np.resize(self.counts, (cap, N_CHANNELS))

    def frames(self) -> Frames:
        n = self.n
        cols = {c: v[:n] for c, v in self.cols.items()}
        return Frames(**cols, dwell=self.dwell[:n].astype(int, copy=False), counts=self.counts[:n],
                      **{c: v[:n].astype(int, copy=False) for c, v in self.board.items()})


def _block_error(block: dict[str, np.ndarray], counts: np.ndarray, prev_t: float) -> tuple[int, str, str] | None:
    """First violation in a block of parsed rows: (index in block, column, message), or None."""
    checks: list[tuple[np.ndarray, str, str]] = []
    for c in COLUMNS[: len(POSE_COLUMNS)]:
        checks.append((~np.isfinite(block[c]), c, "is not finite"))
    checks.append((block["duration"] <= 0, "duration", "must be > 0"))
    for c in ("var_x", "var_y", "var_z"):
        checks.append((block[c] < 0, c, "variance must be >= 0"))
    dw = block["dwell"]
    checks.append((dw != np.round(dw), "dwell", "must be an integer (a dwell index, or -1 while moving)"))
    checks.append(((dw < -1) | (dw > MAX_DWELL), "dwell", "must be -1 (moving) or a dwell index >= 0"))
    t = block["t"]
    checks.append((np.diff(t, prepend=prev_t) < 0, "t", "rows must be in time order"))
    # each frame ends at its own time (durations are > 0): a row at its predecessor's t is the same frame twice
    checks.append((np.diff(t, prepend=prev_t) == 0, "t", "repeats the previous row's time (a duplicated frame)"))
    first: tuple[int, str, str] | None = None
    for mask, column, what in checks:
        if np.any(mask):
            r = int(np.argmax(mask))
            if first is None or r < first[0]:
                first = (r, column, what)
    with np.errstate(invalid="ignore"):
        bad = ~np.isfinite(counts) | (counts < 0) | (counts != np.round(counts)) | (counts > MAX_COUNT)
    if np.any(bad):
        r, k = (int(v) for v in np.argwhere(bad)[0])
        if first is None or r < first[0]:
            v = counts[r, k]
            what = ("is not finite" if not np.isfinite(v) else "counts must be >= 0" if v < 0 else
                    "counts must be integers" if v != round(v) else f"counts must be <= {MAX_COUNT}")
            first = (r, CHANNEL_COLUMNS[k], what)
    return first


def _store(sink: _Sink, block: dict[str, np.ndarray], counts: np.ndarray) -> None:
    n = len(block["t"])
    sink.reserve(n)
    s = slice(sink.n, sink.n + n)
    for c in _FLOAT_COLUMNS:
        sink.cols[c][s] = block[c]
    for c in BOARD_COLUMNS:
        if c in block:
            sink.board[c][s] = block[c]
    sink.dwell[s] = block["dwell"]
    sink.counts[s] = counts
    sink.n += n
    if n:
        sink.last_t = float(block["t"][-1])


def _read_header(file: Path) -> tuple[list[str], int]:
    """Header names (stripped, BOM removed) and the byte length of the header line."""
    try:
        with open(file, "rb") as fh:
            line = fh.readline(1 << 20)
    except FileNotFoundError:
        raise _err(file, "file is missing (a dataset needs frames.csv and scenario.json)") from None
    except IsADirectoryError:
        raise _err(file, "is a directory, not a CSV file") from None
    if not line.strip():
        raise _err(file, "file is empty (expected a header line)")
    text = line.decode("utf-8", errors="replace").removeprefix("\ufeff")
    try:
        header = [h.strip() for h in next(csv.reader([text.rstrip("\r\n")]), [])]
    except csv.Error as exc:  # e.g. a bare CR inside the line: not a header this format knows
        raise _err(file, f"row 1 (header): not a CSV header line ({exc})") from None
    missing = [c for c in COLUMNS if c not in header]
    if missing:
        shown = ", ".join(repr(h) for h in header[:12]) + (", ..." if len(header) > 12 else "")
        raise _err(file, f"row 1 (header): lacks column(s) {', '.join(missing)}; found {shown}")
    dup = [c for c in COLUMNS if header.count(c) > 1]
    if dup:
        raise _err(file, f"row 1 (header): column(s) {', '.join(dup)} appear more than once")
    return header, len(line)


def _scan_lines(file: Path) -> tuple[int, int, bytes]:
    """(number of newlines, line number of the last non-blank line, that line's bytes), streaming."""
    n_newlines = 0
    with open(file, "rb") as fh:
        while chunk := fh.read(_BLOCK_BYTES):
            n_newlines += chunk.count(b"\n")
        size = fh.tell()
        fh.seek(max(0, size - (1 << 20)))
        tail = fh.read()
    stripped = tail.rstrip(b" \t\r\n,")
    start = stripped.rfind(b"\n") + 1
    last = stripped[start:]
    last_lineno = n_newlines - tail[start:].count(b"\n") + 1
    return n_newlines, last_lineno, last


def _truncated_last_row(file: Path, lineno: int, n_fields: int, n_header: int, policy: str) -> None:
    msg = f"row {lineno}: {n_fields} fields, header has {n_header} (truncated last row"
    if policy == "error":
        raise _err(file, msg + "; read with truncated_last_row='skip' to skip it)")
    warnings.warn(f"{file}: {msg}, e.g. a recorder stopped mid-write): skipped it", DatasetWarning, stacklevel=4)


class _FastPathFailed(Exception):
    """The columnar reader met something it does not handle; the exact reader will name it."""


def _read_fast(file: Path, header: list[str], sink: _Sink, progress: Callable[[int, int], None] | None,
               total: int, last_line: bytes, last_lineno: int, policy: str) -> None:
    """Stream frames.csv with pyarrow's CSV reader, block by block, into ``sink``."""
    import pyarrow as pa
    import pyarrow.csv as pacsv

    board = [c for c in BOARD_COLUMNS if c in header]
    names = [h if h in COLUMNS or h in board else f"__extra{i}" for i, h in enumerate(header)]
    invalid: list[tuple[int, int, str]] = []

    def on_invalid(row: Any) -> str:
        try:
            text = row.text
        except UnicodeDecodeError:  # not UTF-8: the exact reader names the row
            text = "\x00"
        if not text.strip(" \t\r\n,"):
            return "skip"  # a blank (or commas-only) line, as the exact reader skips it
        invalid.append((row.actual_columns, row.expected_columns, text))
        return "skip"

    read_opts = pacsv.ReadOptions(column_names=names, skip_rows=1, block_size=_BLOCK_BYTES, use_threads=False)
    parse_opts = pacsv.ParseOptions(invalid_row_handler=on_invalid)
    convert_opts = pacsv.ConvertOptions(
        include_columns=[*COLUMNS, *board], column_types={c: pa.float64() for c in (*COLUMNS, *board)},
        null_values=[],
        strings_can_be_null=False, quoted_strings_can_be_null=False)
    # pyarrow decodes an invalid row's text before calling on_invalid; on non-UTF-8 bytes that fails inside
    # pyarrow ("Exception ignored in on_invalid" on stderr) and the read stops, which sends the file to the exact
    # reader anyway: keep those messages off the user's terminal, pass every other one on
    previous_hook = sys.unraisablehook

    def hook(u: Any) -> None:
        if getattr(u, "object", None) is on_invalid:
            invalid.append((0, 0, "\x00"))
        else:
            previous_hook(u)

    sys.unraisablehook = hook
    try:
        reader = pacsv.open_csv(file, read_options=read_opts, parse_options=parse_opts,
                                convert_options=convert_opts)
        for batch in reader:
            if len(invalid) > 1 or (invalid and invalid[0][0] >= invalid[0][1]):
                raise _FastPathFailed("invalid row")
            block = {c: _float_column(batch.column(c)) for c in (*POSE_COLUMNS, *board)}
            counts = np.column_stack([_float_column(batch.column(c)) for c in CHANNEL_COLUMNS])
            if counts.shape[0] and _block_error(block, counts, sink.last_t) is not None:
                raise _FastPathFailed("invalid value")
            if any(_board_error(block[c], c) is not None for c in board):
                raise _FastPathFailed("invalid value")
            _store(sink, block, counts)
            if progress is not None:
                progress(sink.n, total)
    except (pa.ArrowInvalid, pa.ArrowNotImplementedError, UnicodeDecodeError) as exc:
        raise _FastPathFailed(str(exc)) from None
    finally:
        sys.unraisablehook = previous_hook
    if invalid:
        n_fields, n_header, text = invalid[0]
        if (len(invalid) > 1 or policy == "error"
                or text.encode("utf-8", errors="surrogatepass").rstrip(b" \t\r\n,") != last_line):
            raise _FastPathFailed("invalid row")
        _truncated_last_row(file, last_lineno, n_fields, n_header, policy)


def _float_column(col: Any) -> np.ndarray:
    """A float64 column of the reader (no nulls: ``null_values=[]``) as numpy, a view of its data buffer: pyarrow's
    own ``to_numpy`` imports pandas on its first call (0.3 s of CPU in every process that reads a dataset, for
    nothing else of pandas)."""
    import pyarrow as pa

    if col.null_count or col.type != pa.float64():  # not what the reader is told to make: pyarrow's own way
        return col.to_numpy(zero_copy_only=False)
    return np.frombuffer(col.buffers()[1], dtype=np.float64, count=len(col), offset=col.offset * 8)


def _read_exact(file: Path, header: list[str], sink: _Sink, progress: Callable[[int, int], None] | None,
                total: int, policy: str, block_rows: int = 65536) -> None:
    """Row-by-row reader (Python csv): accepts what the format allows and names the row and column of the
    first thing it does not. Slower than ``_read_fast``; used when that one stops."""
    board = [c for c in BOARD_COLUMNS if c in header]
    idx = [header.index(c) for c in (*COLUMNS, *board)]
    buf = np.empty((block_rows, len(COLUMNS) + len(board)))
    lines = np.empty(block_rows, dtype=np.int64)
    n = 0

    def flush() -> None:
        nonlocal n
        block = {c: buf[:n, i] for i, c in enumerate(POSE_COLUMNS)}
        counts = buf[:n, len(POSE_COLUMNS):len(COLUMNS)]
        bad = _block_error(block, counts, sink.last_t)
        if bad is not None:
            r, column, what = bad
            raise _err(file, f"row {lines[r]}, column {column!r}: {what}")
        for k, c in enumerate(board):
            block[c] = buf[:n, len(COLUMNS) + k]
            r = _board_error(block[c], c)
            if r is not None:
                raise _err(file, f"row {lines[r]}, column {c!r}: {block[c][r]:g} is not a whole number in "
                                 f"[0, {BOARD_COLUMNS[c][1]}]")
        block["dwell"] = block["dwell"].astype(np.int64)
        _store(sink, block, counts.astype(COUNT_DTYPE))
        n = 0
        if progress is not None:
            progress(sink.n, total)

    pending: tuple[int, int] | None = None  # a short row seen: (line, fields); fine only if nothing follows
    with open(file, encoding="utf-8", errors="replace", newline="") as fh:
        reader = csv.reader(fh)
        try:
            next(reader)
            for row in reader:
                if not row or all(not cell.strip() for cell in row):
                    continue
                if pending is not None:
                    raise _err(file, f"row {pending[0]}: {pending[1]} fields, header has {len(header)} "
                                     "(truncated row, and rows follow it)")
                lineno = reader.line_num
                if len(row) != len(header):
                    if len(row) > len(header):
                        raise _err(file, f"row {lineno}: {len(row)} fields, header has {len(header)}")
                    pending = (lineno, len(row))
                    continue
                for j, (c, i) in enumerate(zip((*COLUMNS, *board), idx, strict=True)):
                    cell = row[i].strip()
                    try:
                        buf[n, j] = float(cell)
                    except ValueError:
                        raise _err(file, f"row {lineno}, column {c!r}: {cell[:40]!r} is not a number") from None
                lines[n] = lineno
                n += 1
                if n == block_rows:
                    flush()
        except csv.Error as exc:
            raise _err(file, f"row {reader.line_num}: {exc}") from None
    flush()
    if pending is not None:
        _truncated_last_row(file, pending[0], pending[1], len(header), policy)


def read_frames(file: Path, progress: Callable[[int, int], None] | None = None,
                truncated_last_row: str = "skip") -> Frames:
    """Read and validate frames.csv, streaming: memory is the result's columns plus one block.

    Rows are parsed with pyarrow's CSV reader in blocks; if it stops (an odd cell, a bad value), a row-by-row
    reader re-reads the file and names the row and column of the first problem (DatasetError). Unknown
    columns are ignored; a UTF-8 BOM is allowed. A last row with fewer fields than the header (a recorder
    stopped mid-write) is skipped with a :class:`DatasetWarning` (``truncated_last_row="skip"``, the default)
    or refused (``"error"``). ``progress(rows_read, rows_estimated)`` is called after each block.
    """
    if truncated_last_row not in ("skip", "error"):
        raise ValueError(f"truncated_last_row must be 'skip' or 'error', got {truncated_last_row!r}")
    file = Path(file)
    header, _ = _read_header(file)
    n_newlines, last_lineno, last_line = _scan_lines(file)
    capacity = max(n_newlines, 1)
    total = max(n_newlines - 1, 1)
    sink = _Sink(capacity)
    try:
        _read_fast(file, header, sink, progress, total, last_line, last_lineno, truncated_last_row)
    except _FastPathFailed:  # the exact reader names what the columnar one stopped at
        sink = _Sink(capacity)
        _read_exact(file, header, sink, progress, total, truncated_last_row)
    if sink.n == 0:
        raise _err(file, "no frames (only a header)")
    return sink.frames()


def stderr_progress(label: str, min_interval_s: float = 1.0, after_s: float = 1.0) -> Callable[[int, int], None]:
    """A ``progress`` callback printing ``label: 42 % (123456 rows)`` to stderr, at most every
    ``min_interval_s`` and only once a read has run ``after_s`` (small files stay quiet)."""
    t0 = time.monotonic()
    last = [t0]

    def report(done: int, total: int) -> None:
        now = time.monotonic()
        if now - t0 < after_s or now - last[0] < min_interval_s:
            return
        last[0] = now
        print(f"{label}: {min(100.0, 100.0 * done / max(total, 1)):.0f} % ({done} rows)", file=sys.stderr,
              flush=True)

    return report


def run_dataset(path: str | Path) -> Path:
    """The dataset folder ``path`` names: a ``radseek run`` output folder (no ``frames.csv``, a ``dataset/``
    inside) names its ``dataset/``; any other path names itself. So ``radseek localize runs/X`` reads the flight
    that run recorded instead of failing on the run's own ``scenario.json`` beside a missing ``frames.csv``."""
    path = Path(path)
    if path.is_dir() and not (path / "frames.csv").exists() and (path / "dataset").is_dir():
        return path / "dataset"
    return path


def read_dataset(path: str | Path, progress: Callable[[int, int], None] | None = None,
                 truncated_last_row: str = "skip") -> Dataset:
    """Read and validate a dataset directory's frames and scenario (never its truth.json: see
    :func:`radseek_io.truth.read_dataset_with_truth`). Raises DatasetError naming file, row and column (or key).

    ``progress`` and ``truncated_last_row`` are passed to :func:`read_frames`.
    """
    path = run_dataset(path)
    if not path.is_dir():
        raise DatasetError(f"{path}: not a dataset directory (expected frames.csv and scenario.json inside)")
    if not (path / "frames.csv").exists() and not (path / "scenario.json").exists():
        inner = sorted(p.name for p in path.iterdir() if p.is_dir() and (p / "frames.csv").exists())
        if inner:
            raise DatasetError(f"{path}: holds one dataset per folder ({', '.join(inner)}), as a team run's "
                               f"dataset/ does: give one of them, e.g. {path / inner[0]} (radseek replay takes "
                               "the folder whole, as the team's joint flight)")
    scenario = read_scenario(path / "scenario.json")
    frames = read_frames(path / "frames.csv", progress=progress, truncated_last_row=truncated_last_row)
    return Dataset(frames=frames, scenario=scenario, path=path)


# ---------------------------------------------------------------------------------------- writing


class FrameWriteError(OSError):
    """A frame row could not be written (disk full, file too large, I/O error): names the file, the cause and what
    was kept. The file is cut back to its last whole row, so what was written stays a valid ``frames.csv``."""


class FrameWriter:
    """Append frame records to ``frames.csv`` as they arrive, one ``write`` call per row, so a crash loses nothing.

    Use as a context manager; ``write`` takes one :class:`radseek.frame_record.FrameRecord`.
    ``extra_columns`` are record fields appended after the standard columns (the format allows added
    columns; readers ignore them): the board's ``seq`` and ``flags``. A failed write raises
    :class:`FrameWriteError` after cutting the file back to its last whole row.
    """

    EXTRA_FIELDS = ("seq", "flags")

    def __init__(self, path: str | Path, extra_columns: tuple[str, ...] = (), filename: str = "frames.csv"):
        self.path = Path(path)
        self.path.mkdir(parents=True, exist_ok=True)
        unknown = set(extra_columns) - set(self.EXTRA_FIELDS)
        if unknown:
            raise ValueError(f"extra columns {sorted(unknown)} are not record fields {self.EXTRA_FIELDS}")
        self.extra_columns = tuple(extra_columns)
        self.file = self.path / filename
        self._fd: int | None = os.open(self.file, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        self.bytes = 0  # bytes of whole rows in the file
        self.rows = 0
        self._line([*COLUMNS, *self.extra_columns])

    def write(self, record: FrameRecord) -> None:
        self._line([*record.csv_cells(), *(getattr(record, c) for c in self.extra_columns)])
        self.rows += 1

    def _line(self, cells: Sequence[Any]) -> None:
        if self._fd is None:
            raise FrameWriteError(f"{self.file}: written to after it was closed or failed")
        buf = io.StringIO()
        csv.writer(buf).writerow(cells)
        data = memoryview(buf.getvalue().encode())
        try:
            while data:
                data = data[os.write(self._fd, data):]
        except OSError as exc:
            self._fail(exc)
        self.bytes += len(buf.getvalue().encode())

    def _fail(self, exc: OSError) -> None:
        """Cut the file back to its last whole row, close it, and raise the cause named."""
        fd, self._fd = self._fd, None
        try:
            os.ftruncate(fd, self.bytes)
        except OSError:
            pass
        os.close(fd)
        name = errno.errorcode.get(exc.errno or 0, "")
        err = FrameWriteError(f"cannot write {self.file}: {exc.strerror or exc}{f' ({name})' if name else ''} "
                              f"after {self.bytes} bytes; the {self.rows} rows written stay valid")
        err.errno = exc.errno  # (no strerror/filename: OSError.__str__ would print those instead of the line)
        raise err from exc

    def close(self) -> None:
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None

    def __enter__(self) -> FrameWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def write_json(path: Path, data: dict[str, Any]) -> None:
    path.write_text(json.dumps(data, indent=2) + "\n")


def write_dataset(path: str | Path, frames: Frames, scenario: Scenario, truth: Truth | None = None) -> Path:
    """Write a whole dataset directory (frames.csv, scenario.json, truth.json if given); bounds that
    :func:`read_scenario` would refuse are refused before anything is written."""
    path = Path(path)
    check_bounds(np.asarray(scenario.bounds_min, float), np.asarray(scenario.bounds_max, float),
                 path / "scenario.json")
    with FrameWriter(path) as w:
        for i in range(len(frames)):
            w.write(frames.record(i, scenario.channel_edges_keV))
    write_json(path / "scenario.json", scenario.to_dict())
    if truth is not None:
        write_json(path / "truth.json", truth.to_dict())
    return path
