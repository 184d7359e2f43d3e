"""The ``radseek-dataset/1`` format (shared/spec/dataset-format.md): read, validate, write.

A dataset is a directory with ``frames.csv``, ``scenario.json`` and optionally ``truth.json``. It is
the seam between flying and analysing: every flight writes one, and ``localize``, ``diagnose``,
``compare`` and ``replay`` read one. Readers accept every file written to the contract and ignore
unknown columns and keys; errors name the file, row and column.

``Frames`` holds the columns as numpy arrays (one row per 10 Hz frame); ``Scenario`` the operator's
pre-flight knowledge; ``Truth`` the simulated truth, which estimators must never read (only the
tests and the error report do).
"""

from __future__ import annotations

import csv
import io
import json
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from radseek.frame_record import (
    CHANNEL_COLUMNS,
    COLUMNS,
    COUNT_DTYPE,
    POSE_COLUMNS,
    FrameRecord,
    Spectrum,
)
from radseek.topics import N_CHANNELS

FORMAT = "radseek-dataset/1"

#: The fixed names of physical effects beyond the baseline model (dataset-format.md) and their
#: parameter keys in truth.json. New effects may be added; these keep their meaning.
EFFECTS: dict[str, tuple[str, ...]] = {
    "dead_time": ("tau_s",),
    "wall_attenuation": ("mu_per_m",),
    "anisotropy": ("fraction", "half_angle_deg"),
    "air_attenuation": ("mu_per_m",),
    "second_source": ("x", "y", "z", "cps_at_1m"),
    "background_gradient": ("gx", "gy"),
    "gain_drift": ("percent_per_min",),
    "pose_drift": ("vx", "vy"),
}


class DatasetError(ValueError):
    """A dataset that breaks the format; the message names file, row and column."""


@dataclass(frozen=True)
class Wall:
    """A mapped wall: vertical slab from z=0 to ``height`` centred on segment start-end."""

    start: tuple[float, float]
    end: tuple[float, float]
    thickness: float
    height: float
    material: str = "concrete"

    def to_dict(self) -> dict[str, Any]:
        return {
            "start": list(self.start),
            "end": list(self.end),
            "thickness": self.thickness,
            "height": self.height,
            "material": self.material,
        }


@dataclass(frozen=True)
class Scenario:
    """What the operator knew before the flight (scenario.json)."""

    channel_edges_keV: np.ndarray  # (33,) ascending
    background_cps: float
    source_z: float
    bounds_min: np.ndarray  # (3,)
    bounds_max: np.ndarray  # (3,)
    walls: tuple[Wall, ...] = ()
    nuclide: str = "Cs-137"
    axis: str = "body +x"
    extra: dict[str, Any] = field(default_factory=dict)  # keys this reader does not know

    def to_dict(self) -> dict[str, Any]:
        d = dict(self.extra)
        d.update(
            {
                "format": FORMAT,
                "nuclide": self.nuclide,
                "detector": {"channel_edges_keV": [float(e) for e in self.channel_edges_keV], "axis": self.axis},
                "background_cps": self.background_cps,
                "source_z": self.source_z,
                "bounds": {"min": [float(v) for v in self.bounds_min], "max": [float(v) for v in self.bounds_max]},
                "walls": [w.to_dict() for w in self.walls],
            }
        )
        return d


@dataclass(frozen=True)
class TruthSource:
    x: float
    y: float
    z: float
    cps_at_1m: float
    nuclide: str = "Cs-137"

    @property
    def position(self) -> np.ndarray:
        return np.array([self.x, self.y, self.z])


@dataclass(frozen=True)
class Truth:
    """The simulated truth (truth.json): for tests and error reports only, never for estimators."""

    sources: tuple[TruthSource, ...]
    background_cps: float
    effects: dict[str, dict[str, float]]

    def all_sources(self) -> tuple[TruthSource, ...]:
        """The primary sources plus a ``second_source`` effect's source, if any."""
        extra = self.effects.get("second_source")
        if not extra:
            return self.sources
        s = TruthSource(extra["x"], extra["y"], extra.get("z", 0.0), extra["cps_at_1m"], self.sources[0].nuclide)
        return (*self.sources, s)

    def to_dict(self) -> dict[str, Any]:
        return {
            "sources": [
                {"x": s.x, "y": s.y, "z": s.z, "cps_at_1m": s.cps_at_1m, "nuclide": s.nuclide} for s in self.sources
            ],
            "background_cps": self.background_cps,
            "effects": self.effects,
        }


@dataclass(frozen=True)
class Frames:
    """frames.csv as arrays: one entry per frame, rows in time order."""

    t: np.ndarray
    duration: np.ndarray
    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    yaw: np.ndarray
    var_x: np.ndarray
    var_y: np.ndarray
    var_z: np.ndarray
    dwell: np.ndarray  # int, -1 while moving
    counts: np.ndarray  # (n, 32) COUNT_DTYPE when read or recorded (simulators may hold expected counts)

    def __len__(self) -> int:
        return len(self.t)

    @property
    def positions(self) -> np.ndarray:
        """(n, 3) estimated detector positions."""
        return np.column_stack([self.x, self.y, self.z])

    @property
    def pose_variances(self) -> np.ndarray:
        """(n, 3) variances of the position estimate."""
        return np.column_stack([self.var_x, self.var_y, self.var_z])

    @property
    def total_counts(self) -> np.ndarray:
        return self.counts.sum(axis=1)

    def select(self, mask: np.ndarray) -> Frames:
        return Frames(**{name: getattr(self, name)[mask] for name in self.__dataclass_fields__})

    @staticmethod
    def from_rows(rows: np.ndarray) -> Frames:
        """Build from an (n, 42) array in ``COLUMNS`` order."""
        rows = np.asarray(rows, dtype=float).reshape(-1, len(COLUMNS))
        cols = {name: rows[:, i] for i, name in enumerate(POSE_COLUMNS)}
        cols["dwell"] = cols["dwell"].astype(int)
        return Frames(**cols, counts=rows[:, len(POSE_COLUMNS) :].astype(COUNT_DTYPE))

    @staticmethod
    def from_records(records: Sequence[FrameRecord]) -> Frames:
        """The columns of a list of frame records (empty list: zero frames)."""
        cols = {name: np.array([getattr(r, name) for r in records], dtype=float) for name in POSE_COLUMNS}
        cols["dwell"] = np.array([r.dwell for r in records], dtype=int)
        counts = np.array([r.counts for r in records], dtype=COUNT_DTYPE).reshape(-1, N_CHANNELS)
        return Frames(**cols, counts=counts)

    def record(self, i: int, channel_edges_keV: np.ndarray | None = None) -> FrameRecord:
        """Frame ``i`` as a record (no board sequence number or flags: frames.csv keeps them apart)."""
        pose = {name: float(getattr(self, name)[i]) for name in POSE_COLUMNS if name not in ("duration", "dwell")}
        spectrum = Spectrum(self.counts[i], float(self.duration[i]), None, channel_edges_keV)
        return FrameRecord(spectrum=spectrum, dwell=int(self.dwell[i]), **pose)


@dataclass(frozen=True)
class Dataset:
    frames: Frames
    scenario: Scenario
    truth: Truth | None = None
    path: Path | None = None

    @property
    def name(self) -> str:
        return self.path.name if self.path else "<memory>"


# ---------------------------------------------------------------------------------------- reading


def _err(file: Path, msg: str) -> DatasetError:
    return DatasetError(f"{file}: {msg}")


def _get(d: dict, keypath: str, file: Path, kind: type | tuple = (int, float)) -> Any:
    cur: Any = d
    for part in keypath.split("."):
        if not isinstance(cur, dict) or part not in cur:
            raise _err(file, f"missing key {keypath!r}")
        cur = cur[part]
    if kind in ((int, float), float) and (isinstance(cur, bool) or not isinstance(cur, int | float)):
        raise _err(file, f"key {keypath!r} must be a number, got {cur!r}")
    if kind in ((int, float), float) and not math.isfinite(cur):
        raise _err(file, f"key {keypath!r} must be finite, got {cur!r}")
    return cur


def _vector(d: dict, keypath: str, file: Path, n: int) -> np.ndarray:
    v = _get(d, keypath, file, kind=list)
    if not isinstance(v, list) or len(v) != n or not all(isinstance(a, int | float) for a in v):
        raise _err(file, f"key {keypath!r} must be a list of {n} numbers, got {v!r}")
    return np.asarray(v, dtype=float)


def read_scenario(file: Path) -> Scenario:
    try:
        d = json.loads(file.read_text())
    except FileNotFoundError:
        raise _err(file, "file is missing (a dataset needs frames.csv and scenario.json)") from None
    except json.JSONDecodeError as exc:
        raise _err(file, f"not valid JSON: {exc}") from None
    if not isinstance(d, dict):
        raise _err(file, "must hold a JSON object")
    fmt = d.get("format", FORMAT)
    if not str(fmt).startswith("radseek-dataset/1"):
        raise _err(file, f"key 'format' is {fmt!r}; this reader understands radseek-dataset/1")
    edges_raw = _get(d, "detector.channel_edges_keV", file, kind=list)
    if not isinstance(edges_raw, list) or len(edges_raw) != N_CHANNELS + 1:
        raise _err(file, f"key 'detector.channel_edges_keV' must list {N_CHANNELS + 1} numbers")
    edges = np.asarray(edges_raw, dtype=float)
    if not np.all(np.diff(edges) > 0):
        raise _err(file, "key 'detector.channel_edges_keV' must be strictly ascending")
    background = float(_get(d, "background_cps", file))
    if background < 0:
        raise _err(file, f"key 'background_cps' must be >= 0, got {background}")
    bmin = _vector(d, "bounds.min", file, 3)
    bmax = _vector(d, "bounds.max", file, 3)
    if np.any(bmax < bmin):
        raise _err(file, "key 'bounds': max must be >= min on every axis")
    walls = []
    for i, w in enumerate(d.get("walls", []) or []):
        where = f"walls[{i}]"
        if not isinstance(w, dict):
            raise _err(file, f"{where} must be an object")
        try:
            start = tuple(float(a) for a in w["start"])
            end = tuple(float(a) for a in w["end"])
            thickness = float(w["thickness"])
            height = float(w.get("height", 3.0))
        except (KeyError, TypeError, ValueError) as exc:
            raise _err(file, f"{where}: bad or missing field ({exc})") from None
        if len(start) != 2 or len(end) != 2:
            raise _err(file, f"{where}: start and end must be [x, y]")
        if thickness <= 0 or height <= 0:
            raise _err(file, f"{where}: thickness and height must be > 0")
        walls.append(Wall(start, end, thickness, height, str(w.get("material", "concrete"))))  # type: ignore[arg-type]
    known = {"format", "nuclide", "detector", "background_cps", "source_z", "bounds", "walls"}
    return Scenario(
        channel_edges_keV=edges,
        background_cps=background,
        source_z=float(d.get("source_z", 0.0)),
        bounds_min=bmin,
        bounds_max=bmax,
        walls=tuple(walls),
        nuclide=str(d.get("nuclide", "Cs-137")),
        axis=str(d.get("detector", {}).get("axis", "body +x")),
        extra={k: v for k, v in d.items() if k not in known},
    )


def read_truth(file: Path) -> Truth | None:
    if not file.exists():
        return None
    try:
        d = json.loads(file.read_text())
    except json.JSONDecodeError as exc:
        raise _err(file, f"not valid JSON: {exc}") from None
    sources = []
    for i, s in enumerate(d.get("sources", [])):
        try:
            sources.append(
                TruthSource(float(s["x"]), float(s["y"]), float(s.get("z", 0.0)), float(s["cps_at_1m"]),
                            str(s.get("nuclide", "Cs-137")))
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise _err(file, f"sources[{i}]: bad or missing field ({exc})") from None
    effects = d.get("effects", {}) or {}
    if not isinstance(effects, dict):
        raise _err(file, "key 'effects' must be an object")
    return Truth(tuple(sources), float(d.get("background_cps", float("nan"))), effects)


def read_frames(file: Path) -> Frames:
    try:
        text = file.read_text()
    except FileNotFoundError:
        raise _err(file, "file is missing (a dataset needs frames.csv and scenario.json)") from None
    reader = csv.reader(io.StringIO(text))
    try:
        header = [h.strip() for h in next(reader)]
    except StopIteration:
        raise _err(file, "file is empty (expected a header line)") from None
    missing = [c for c in COLUMNS if c not in header]
    if missing:
        raise _err(file, f"header lacks column(s) {', '.join(missing)}")
    idx = [header.index(c) for c in COLUMNS]
    rows = []
    for rowno, row in enumerate(reader, start=2):
        if not row or all(not cell.strip() for cell in row):
            continue
        if len(row) < len(header):
            raise _err(file, f"row {rowno}: {len(row)} fields, header has {len(header)} (truncated row?)")
        values = []
        for c, i in zip(COLUMNS, idx, strict=True):
            cell = row[i].strip()
            try:
                v = float(cell)
            except ValueError:
                raise _err(file, f"row {rowno}, column {c!r}: {cell!r} is not a number") from None
            if not math.isfinite(v):
                raise _err(file, f"row {rowno}, column {c!r}: {cell!r} is not finite")
            values.append(v)
        rows.append(values)
    if not rows:
        raise _err(file, "no frames (only a header)")
    arr = np.asarray(rows)
    frames = Frames.from_rows(arr)
    _validate_frames(frames, file)
    return frames


def _validate_frames(f: Frames, file: Path) -> None:
    def bad(mask: np.ndarray, column: str, what: str) -> None:
        if np.any(mask):
            r = int(np.argmax(mask))
            raise _err(file, f"row {r + 2}, column {column!r}: {what}")

    bad(f.duration <= 0, "duration", "must be > 0")
    for c in ("var_x", "var_y", "var_z"):
        bad(getattr(f, c) < 0, c, "variance must be >= 0")
    bad(f.dwell < -1, "dwell", "must be -1 (moving) or a dwell index >= 0")
    neg = f.counts < 0
    if np.any(neg):
        r, k = np.argwhere(neg)[0]
        raise _err(file, f"row {r + 2}, column {CHANNEL_COLUMNS[k]!r}: counts must be >= 0")
    frac = f.counts != np.round(f.counts)
    if np.any(frac):
        r, k = np.argwhere(frac)[0]
        raise _err(file, f"row {r + 2}, column {CHANNEL_COLUMNS[k]!r}: counts must be integers")
    bad(np.r_[False, np.diff(f.t) < 0], "t", "rows must be in time order")


def read_dataset(path: str | Path) -> Dataset:
    """Read and validate a dataset directory. Raises DatasetError naming file, row and column."""
    path = Path(path)
    if not path.is_dir():
        raise DatasetError(f"{path}: not a dataset directory (expected frames.csv and scenario.json inside)")
    scenario = read_scenario(path / "scenario.json")
    frames = read_frames(path / "frames.csv")
    truth = read_truth(path / "truth.json")
    return Dataset(frames=frames, scenario=scenario, truth=truth, path=path)


# ---------------------------------------------------------------------------------------- writing


class FrameWriter:
    """Append frame records to ``frames.csv`` as they arrive, flushed per row, so a crash loses nothing.

    Use as a context manager; ``write`` takes one :class:`radseek.frame_record.FrameRecord`.
    ``extra_columns`` are record fields appended after the standard columns (the format allows added
    columns; readers ignore them): the board's ``seq`` and ``flags``.
    """

    EXTRA_FIELDS = ("seq", "flags")

    def __init__(self, path: str | Path, extra_columns: tuple[str, ...] = (), filename: str = "frames.csv"):
        self.path = Path(path)
        self.path.mkdir(parents=True, exist_ok=True)
        unknown = set(extra_columns) - set(self.EXTRA_FIELDS)
        if unknown:
            raise ValueError(f"extra columns {sorted(unknown)} are not record fields {self.EXTRA_FIELDS}")
        self.extra_columns = tuple(extra_columns)
        self._fh = open(self.path / filename, "w", newline="")  # noqa: SIM115 (closed in close())
        self._csv = csv.writer(self._fh)
        self._csv.writerow([*COLUMNS, *self.extra_columns])
        self.rows = 0

    def write(self, record: FrameRecord) -> None:
        self._csv.writerow([*record.csv_cells(), *(getattr(record, c) for c in self.extra_columns)])
        self._fh.flush()
        self.rows += 1

    def close(self) -> None:
        if not self._fh.closed:
            self._fh.close()

    def __enter__(self) -> FrameWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def write_json(path: Path, data: dict[str, Any]) -> None:
    path.write_text(json.dumps(data, indent=2) + "\n")


def write_dataset(path: str | Path, frames: Frames, scenario: Scenario, truth: Truth | None = None) -> Path:
    """Write a whole dataset directory (frames.csv, scenario.json, truth.json if given)."""
    path = Path(path)
    with FrameWriter(path) as w:
        for i in range(len(frames)):
            w.write(frames.record(i, scenario.channel_edges_keV))
    write_json(path / "scenario.json", scenario.to_dict())
    if truth is not None:
        write_json(path / "truth.json", truth.to_dict())
    return path
