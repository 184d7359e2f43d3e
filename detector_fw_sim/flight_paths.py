"""Flight paths for simulated datasets: dwell points and the trajectory flown between them.

A ``FlightPath`` is a start pose and a list of waypoints (x, y, z, yaw, dwell_s, spin_turns): the
vehicle flies straight to each at up to ``speed`` m/s (trapezoidal profile, ``accel`` m/s^2, yaw
turning linearly on the way), then hovers ``dwell_s`` seconds (0 = fly through, no dwell index),
turning ``spin_turns`` full turns while it dwells. ``Trajectory.sample`` gives the true pose at any
time and the dwell index (-1 while moving), the conventions of shared/datasets/README.md.

Built-in paths (all derived from the scene, with seeded jitter): ``lattice`` (paper 003 sec. IV:
1 far point + 8 in a grid around the source), ``spin`` (the lattice at 1.2 m plus a point over the
source, one turn per dwell), ``lawnmower`` (rows over the bounds; background dwells far away
outdoors), ``close-pass`` (low passes straight over the source, then dwells 1-6 m from it). A CSV
with columns x, y, z, yaw, dwell_s (optional spin_turns) is read by ``read_path_csv``.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from detector_fw_sim.scene import Scene

BUILTIN_PATHS = ("lattice", "spin", "lawnmower", "close-pass")


class FlightPathError(ValueError):
    """A path file or name that cannot be flown; the message names file, row and column."""


@dataclass(frozen=True)
class FlightPath:
    start: tuple[float, float, float, float]  # x, y, z, yaw
    waypoints: np.ndarray  # (M, 6): x, y, z, yaw, dwell_s, spin_turns
    name: str = "path"
    speed: float = 1.0
    accel: float = 0.5
    settle_s: float = 0.3


@dataclass
class Trajectory:
    """Piecewise motion: segment k runs [t0[k], t1[k]] from pose a[k] to pose b[k]."""

    t0: np.ndarray
    t1: np.ndarray
    a: np.ndarray  # (S, 4)
    b: np.ndarray  # (S, 4) (yaw of b may exceed pi: unwrapped so yaw interpolates linearly)
    dwell: np.ndarray  # (S,) dwell index or -1
    profile: np.ndarray  # (S,) 0 = hover (linear yaw), 1 = trapezoidal transit
    vmax: np.ndarray = field(default_factory=lambda: np.zeros(0))
    accel: float = 0.5

    @property
    def duration(self) -> float:
        return float(self.t1[-1])

    def _fraction(self, k: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """Share of the distance covered after tau s of segment k (trapezoid for transits)."""
        T = self.t1[k] - self.t0[k]
        lin = np.where(T > 0, tau / np.where(T > 0, T, 1.0), 1.0)
        dist = np.linalg.norm(self.b[k, :3] - self.a[k, :3], axis=-1)
        a, v = self.accel, self.vmax[k]
        ta = np.minimum(v / a, T / 2)
        vpeak = a * ta
        s = np.where(tau < ta, 0.5 * a * tau**2,
                     np.where(tau < T - ta, 0.5 * a * ta**2 + vpeak * (tau - ta),
                              dist - 0.5 * a * np.maximum(T - tau, 0) ** 2))
        trap = np.clip(s / np.where(dist > 0, dist, 1.0), 0, 1)
        return np.where((self.profile[k] == 1) & (dist > 0), trap, np.clip(lin, 0, 1))

    def sample(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(N, 4) true poses (x, y, z, yaw wrapped to (-pi, pi]) and (N,) dwell indices at times t."""
        t = np.clip(np.asarray(t, dtype=float), 0.0, self.duration)
        k = np.clip(np.searchsorted(self.t1, t, side="left"), 0, len(self.t1) - 1)
        tau = t - self.t0[k]
        f = self._fraction(k, tau)
        pos = self.a[k, :3] + f[:, None] * (self.b[k, :3] - self.a[k, :3])
        T = self.t1[k] - self.t0[k]
        fy = np.where(self.profile[k] == 1, f, np.clip(tau / np.where(T > 0, T, 1.0), 0, 1))
        yaw = self.a[k, 3] + fy * (self.b[k, 3] - self.a[k, 3])
        yaw = (yaw + np.pi) % (2 * np.pi) - np.pi
        return np.column_stack([pos, yaw]), self.dwell[k]


def _wrap_delta(a: float, b: float) -> float:
    return (b - a + math.pi) % (2 * math.pi) - math.pi


def build_trajectory(path: FlightPath) -> Trajectory:
    t = 0.0
    cur = np.array(path.start, dtype=float)
    t0, t1, A, B, dw, prof, vm = [], [], [], [], [], [], []
    dwell_index = 0
    for x, y, z, yaw, dwell_s, spin in path.waypoints:
        target = np.array([x, y, z], dtype=float)
        dist = float(np.linalg.norm(target - cur[:3]))
        a, v = path.accel, path.speed
        T = 2 * math.sqrt(dist / a) if dist < v * v / a else dist / v + v / a
        T = max(T, 0.5) + (path.settle_s if dwell_s > 0 else 0.0)
        end = np.r_[target, cur[3] + _wrap_delta(cur[3], yaw)]
        t0.append(t), t1.append(t + T), A.append(cur.copy()), B.append(end), dw.append(-1), prof.append(1), vm.append(v)
        t += T
        cur = end
        if dwell_s > 0:
            spin_end = cur.copy()
            spin_end[3] += 2 * math.pi * spin
            t0.append(t), t1.append(t + dwell_s), A.append(cur.copy()), B.append(spin_end), dw.append(dwell_index)
            prof.append(0), vm.append(v)
            t += dwell_s
            cur = spin_end
            dwell_index += 1
    return Trajectory(np.array(t0), np.array(t1), np.array(A), np.array(B), np.array(dw), np.array(prof),
                      np.array(vm), path.accel)


# ------------------------------------------------------------------------------------ built-in paths


def _source_xy(scene: Scene) -> np.ndarray:
    return np.array(scene.sources[0].position[:2], dtype=float)


def lattice(scene: Scene, rng: np.random.Generator, z: tuple[float, float] = (1.3, 1.7), spacing: float = 1.6,
            spin_turns: float = 0.0, centre_point: bool = False) -> FlightPath:
    """Paper 003's fixed lattice: one far point near a corner of the bounds, then 8 points of a 3 x 3
    grid (spacing ``spacing``) around the source, flown as a ring."""
    lo, hi = np.array(scene.bounds.min[:2]), np.array(scene.bounds.max[:2])
    c = _source_xy(scene) + rng.normal(0, 0.15, 2)
    ring = [(1, 1), (0, 1), (-1, 1), (-1, 0), (-1, -1), (0, -1), (1, -1), (1, 0)]
    pts = [hi - np.array([1.3, 1.1])]
    pts += [c + spacing * np.array(o) + rng.normal(0, 0.05, 2) for o in ring]
    if centre_point:
        pts.append(c + rng.normal(0, 0.1, 2))
    pts = [np.clip(p, lo + 0.3, hi - 0.3) if np.all(hi - lo > 0.6) else p for p in pts]
    n = len(pts)
    wp = np.column_stack([np.array(pts), rng.uniform(*z, n), rng.uniform(-math.pi, math.pi, n),
                          rng.uniform(5.0, 15.0, n), np.full(n, spin_turns) * rng.choice([-1, 1], n)])
    start = (*(hi - np.array([0.7, 0.6])), float(np.mean(z)), 0.0)
    return FlightPath(start, wp, "spin" if spin_turns else "lattice")


def lawnmower(scene: Scene, rng: np.random.Generator, spacing: float | None = None) -> FlightPath:
    """Rows across the bounds at 2 m (outdoors) or 1.5 m; background dwells far from the area outdoors."""
    lo, hi = np.array(scene.bounds.min[:2]), np.array(scene.bounds.max[:2])
    outdoor = scene.kind == "outdoor"
    z = 2.0 if outdoor else 1.5
    spacing = spacing or (2.5 if outdoor else 1.5)
    ys = np.arange(lo[1] + spacing / 2, hi[1], spacing)
    rows = []
    for i, y in enumerate(ys):
        xs = (lo[0] + 0.5, hi[0] - 0.5) if i % 2 == 0 else (hi[0] - 0.5, lo[0] + 0.5)
        rows += [(xs[0], y, z, 0.0 if i % 2 == 0 else math.pi, 0.0, 0.0), (xs[1], y, z, 0.0 if i % 2 == 0 else math.pi,
                                                                           0.0, 0.0)]
    if outdoor:
        far = lo - np.array([40.0, 30.0])  # 50 m from the corner, 60-70 m from the area (paper 000)
    else:
        far = lo + 0.5
    bg_start = (far[0], far[1], z, 0.0, float(rng.uniform(10, 15)), 0.0)
    bg_end = (far[0] + 1.0, far[1] + 1.0, z, math.pi, float(rng.uniform(10, 15)), 0.0)
    wp = np.array([bg_start, *rows, bg_end], dtype=float)
    wp[:, :2] += rng.normal(0, 0.05, (len(wp), 2))
    return FlightPath((far[0] - 0.5, far[1] - 0.5, z, 0.0), wp, "lawnmower")


def close_pass(scene: Scene, rng: np.random.Generator) -> FlightPath:
    """A far dwell, two low passes straight over the source (0.8 m), then dwells 1-6 m from it."""
    lo, hi = np.array(scene.bounds.min[:2]), np.array(scene.bounds.max[:2])
    s = np.array(scene.sources[0].position, dtype=float)
    far = lo + 1.0
    wp = [(far[0], far[1], 1.5, rng.uniform(-math.pi, math.pi), 8.0, 0.0),
          (lo[0] + 0.5, s[1], 0.8 + s[2], 0.0, 0.0, 0.0), (hi[0] - 0.5, s[1], 0.8 + s[2], 0.0, 0.0, 0.0),
          (s[0], hi[1] - 0.5, 0.8 + s[2], -math.pi / 2, 0.0, 0.0),
          (s[0], lo[1] + 0.5, 0.8 + s[2], -math.pi / 2, 0.0, 0.0)]
    for d in (1.0, 1.5, 2.0, 3.0, 4.0, 6.0):
        z = rng.uniform(1.0, min(2.0, d))
        h = math.sqrt(max(d * d - z * z, 0.0))
        bearing = rng.uniform(-math.pi, math.pi)
        xy = np.clip(s[:2] + h * np.array([math.cos(bearing), math.sin(bearing)]), lo + 0.3, hi - 0.3)
        wp.append((xy[0], xy[1], z + s[2], rng.uniform(-math.pi, math.pi), rng.uniform(5.0, 12.0), 0.0))
    return FlightPath((far[0] - 0.5, far[1] - 0.5, 1.5, 0.0), np.array(wp, dtype=float), "close-pass")


def read_path_csv(file: str | Path) -> FlightPath:
    """A path from CSV columns x, y, z, yaw, dwell_s (spin_turns optional); the first row is the start."""
    file = Path(file)
    try:
        rows = list(csv.DictReader(file.read_text().splitlines()))
    except FileNotFoundError:
        raise FlightPathError(f"{file}: path file not found") from None
    if not rows:
        raise FlightPathError(f"{file}: no waypoints (need a header x,y,z,yaw,dwell_s and rows)")
    missing = [c for c in ("x", "y", "z", "yaw", "dwell_s") if c not in rows[0]]
    if missing:
        raise FlightPathError(f"{file}: header lacks column(s) {', '.join(missing)}")
    wp = []
    for i, r in enumerate(rows, start=2):
        vals = []
        for c in ("x", "y", "z", "yaw", "dwell_s", "spin_turns"):
            cell = (r.get(c) or ("0" if c == "spin_turns" else "")).strip()
            try:
                v = float(cell)
            except ValueError:
                raise FlightPathError(f"{file}: row {i}, column {c!r}: {cell!r} is not a number") from None
            if not math.isfinite(v):
                raise FlightPathError(f"{file}: row {i}, column {c!r}: {cell!r} is not finite")
            vals.append(v)
        if vals[4] < 0:
            raise FlightPathError(f"{file}: row {i}, column 'dwell_s': must be >= 0, got {vals[4]}")
        wp.append(vals)
    arr = np.array(wp)
    return FlightPath(tuple(arr[0, :4]), arr, file.stem)  # type: ignore[arg-type]


def make_path(name_or_file: str | Path | FlightPath, scene: Scene, rng: np.random.Generator) -> FlightPath:
    if isinstance(name_or_file, FlightPath):
        return name_or_file
    name = str(name_or_file)
    if name == "lattice":
        return lattice(scene, rng)
    if name == "spin":
        return lattice(scene, rng, z=(1.15, 1.3), spin_turns=1.0, centre_point=True)
    if name == "lawnmower":
        return lawnmower(scene, rng)
    if name == "close-pass":
        return close_pass(scene, rng)
    if name.lower().endswith(".csv") or Path(name).exists():
        return read_path_csv(name)
    raise FlightPathError(f"unknown path {name!r}: use one of {', '.join(BUILTIN_PATHS)} or a CSV file")
