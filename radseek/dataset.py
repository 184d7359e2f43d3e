"""The ``radseek-dataset/1`` types (shared/spec/dataset-format.md): what a dataset holds, not how it is read.

A dataset is a directory with ``frames.csv``, ``scenario.json`` and optionally ``truth.json``; reading,
validating and writing it is the I/O layer's (:mod:`radseek_io.dataset`, :mod:`radseek_io.truth`).

``Frames`` holds the columns as numpy arrays (one row per 10 Hz frame); ``Scenario`` the operator's
pre-flight knowledge; ``Dataset.truth`` the simulated truth (:mod:`radseek.truth`), which estimators must
never read (only the tests, the launchers and the error reports of the command-line tools do).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from radseek.frame_record import COLUMNS, COUNT_DTYPE, POSE_COLUMNS, FrameRecord, as_counts
from radseek.spectrum import Spectrum
from radseek.topics import N_CHANNELS

if TYPE_CHECKING:  # the type only: flight software imports this module and never the truth
    from radseek.truth import Truth

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
    #: the operator's attenuation coefficient of the air flown through at the nuclide's main line (1/m; NIST
    #: XCOM dry air is 0.0093 at 662 keV): every model of the scenario then attenuates by exp(-mu d). 0: the
    #: baseline model (no air), as in every dataset without the key
    air_mu_per_m: float = 0.0
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
        if self.air_mu_per_m > 0:
            d["air_mu_per_m"] = self.air_mu_per_m
        return d


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
    #: int, the team index of the vehicle that recorded each frame (0 for a single vehicle)
    vehicle: np.ndarray | None = None
    #: int, the odometry walk each frame's pose belongs to (one per vehicle flight): its pose errors are one random
    #: walk. Not given: a frame earlier than its predecessor starts the next walk (frames of several flights
    #: concatenated flight by flight, each in time order), the one place this is inferred
    walk: np.ndarray | None = None
    #: int, the board's frame counter (-1: not known, e.g. read from a file without the column)
    seq: np.ndarray | None = None
    #: int, the board's status flags (``topics.FLAG_*``; 0: none known)
    flags: np.ndarray | None = None

    def __post_init__(self) -> None:
        n = len(self.t)
        if self.seq is None:
            object.__setattr__(self, "seq", np.full(n, -1, dtype=int))
        if self.flags is None:
            object.__setattr__(self, "flags", np.zeros(n, dtype=int))
        if self.vehicle is None:
            object.__setattr__(self, "vehicle", np.zeros(n, dtype=int))
        if self.walk is None:
            t = np.asarray(self.t, dtype=float)
            object.__setattr__(self, "walk", np.cumsum(np.r_[False, t[1:] < t[:-1]]).astype(int) if n
                               else np.zeros(0, dtype=int))
        for name in ("vehicle", "walk", "seq", "flags"):
            if len(getattr(self, name)) != n:
                raise ValueError(f"Frames.{name} has {len(getattr(self, name))} entries for {n} frames")

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
        for name in ("vehicle", "seq", "flags"):
            cols[name] = np.array([getattr(r, name) for r in records], dtype=int)
        counts = np.array([r.counts for r in records], dtype=COUNT_DTYPE).reshape(-1, N_CHANNELS)
        return Frames(**cols, counts=counts)

    def record(self, i: int, channel_edges_keV: np.ndarray | None = None) -> FrameRecord:
        """Frame ``i`` as a record (a sequence number not known is 0)."""
        pose = {name: float(getattr(self, name)[i]) for name in POSE_COLUMNS if name not in ("duration", "dwell")}
        spectrum = Spectrum(as_counts(self.counts[i]), realtime=float(self.duration[i]),
                            bin_edges_kev=channel_edges_keV)
        return FrameRecord(spectrum=spectrum, dwell=int(self.dwell[i]), seq=max(int(self.seq[i]), 0),
                           flags=int(self.flags[i]), vehicle=int(self.vehicle[i]), **pose)


@dataclass(frozen=True)
class Dataset:
    frames: Frames
    scenario: Scenario
    truth: Truth | None = None
    path: Path | None = None

    @property
    def name(self) -> str:
        return self.path.name if self.path else "<memory>"
