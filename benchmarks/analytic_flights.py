"""Analytic flights for tests and benchmarks: frames with exact or Poisson counts from the baseline model.

``lattice_flight`` replicates paper 003's fixed lattice (1 far point + 8 around the source) without
effects, so tests need neither the simulator nor the model; ``expected_total`` is the baseline model
of dataset-format.md (optionally with paralyzable dead time, paper 000 eq. 10).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from radseek.count_model import dead_time, expected_rate
from radseek.dataset import Dataset, Frames, Scenario
from radseek.frame_record import COLUMNS, POSE_COLUMNS
from radseek.truth import Truth, TruthSource

__all__ = ["expected_total", "dwell_frames", "lattice_points", "lattice_flight", "scenario_for"]


def expected_total(pos: np.ndarray, sources: Sequence[tuple[float, float, float, float]], background: float,
                   duration: np.ndarray | float, tau_s: float = 0.0) -> np.ndarray:
    """Expected total counts at detector positions (N, 3): T * (sum S/d^2 + B), with exp(-n tau) dead time
    (:mod:`radseek.count_model`)."""
    pos = np.atleast_2d(pos)
    n = np.full(len(pos), float(background))
    for x, y, z, s in sources:
        n = n + expected_rate(((pos - [x, y, z]) ** 2).sum(axis=1), s)
    return dead_time(n, tau_s) * duration


def scenario_for(bounds_min=(0.0, 0.0, 0.0), bounds_max=(10.0, 8.0, 0.5), background: float = 30.0,
                 source_z: float = 0.0, walls=()) -> Scenario:
    return Scenario(channel_edges_keV=np.linspace(40, 1600, 33), background_cps=float(background),
                    source_z=source_z, bounds_min=np.asarray(bounds_min, float),
                    bounds_max=np.asarray(bounds_max, float), walls=tuple(walls))


def dwell_frames(points: np.ndarray, sources: Sequence[tuple[float, float, float, float]], background: float,
                 dwell_s: float | Sequence[float] = 10.0, frame_s: float = 0.1, rng: np.random.Generator | None = None,
                 tau_s: float = 0.0, pose_sd: float = 0.0, exact: bool = False) -> Frames:
    """Frames of dwells at ``points`` (K, 3): Poisson counts (or exact expected counts with ``exact``).

    ``pose_sd`` adds a per-dwell recorded-pose offset (true pose stays at the point), as the shared datasets do.
    """
    rng = rng or np.random.default_rng(0)
    points = np.atleast_2d(np.asarray(points, dtype=float))
    dws = np.broadcast_to(np.asarray(dwell_s, dtype=float), (len(points),))
    rows = []
    t = 0.0
    for k, (p, dw) in enumerate(zip(points, dws, strict=True)):
        n = max(1, round(dw / frame_s))
        true = np.repeat(p[None], n, axis=0)
        lam = expected_total(true, sources, background, frame_s, tau_s)
        counts = lam if exact else rng.poisson(lam).astype(float)
        rec = p + (rng.normal(0, pose_sd, 3) * [1, 1, 0.3] if pose_sd else 0.0)
        for i in range(n):
            t += frame_s
            r = np.zeros(len(COLUMNS))
            r[:len(POSE_COLUMNS)] = [t, frame_s, rec[0], rec[1], rec[2], 0.0, pose_sd**2, pose_sd**2,
                                     (0.3 * pose_sd) ** 2, k]
            r[len(POSE_COLUMNS) + 10] = counts[i]  # all counts in one channel: only totals matter here
            rows.append(r)
    if exact:
        rows = np.asarray(rows)
        f = Frames.from_rows(rows)
        # keep the exact (non-integer) expectation: from_rows casts counts to int
        return Frames(**{k: getattr(f, k) for k in Frames.__dataclass_fields__ if k != "counts"},
                      counts=rows[:, len(POSE_COLUMNS):])
    return Frames.from_rows(np.asarray(rows))


def lattice_points(source_xy: tuple[float, float], height: float = 1.5, spacing: float = 1.5,
                   far: tuple[float, float] = (0.5, 0.5)) -> np.ndarray:
    """Paper 003's fixed lattice: one far point (just above background) + 8 points around the source."""
    sx, sy = source_xy
    ring = [(sx + dx * spacing, sy + dy * spacing) for dx in (-1, 0, 1) for dy in (-1, 0, 1) if (dx, dy) != (0, 0)]
    pts = [(far[0], far[1])] + ring
    return np.array([[x, y, height] for x, y in pts])


def lattice_flight(seed: int, source: tuple[float, float] | None = None, cps_at_1m: float = 1600.0,
                   background: float = 30.0, dwell_s: float = 10.0, pose_sd: float = 0.0, tau_s: float = 0.0,
                   bg_error: float = 0.0) -> Dataset:
    """A seeded 9-point lattice flight over a random source in a 10 m x 8 m room (no effects)."""
    rng = np.random.default_rng(seed)
    if source is None:
        source = (float(rng.uniform(3.0, 7.0)), float(rng.uniform(2.5, 5.5)))
    pts = lattice_points(source)
    src = [(source[0], source[1], 0.0, cps_at_1m)]
    frames = dwell_frames(pts, src, background, dwell_s, rng=rng, tau_s=tau_s, pose_sd=pose_sd)
    scen = scenario_for(background=background * (1 + bg_error))
    truth = Truth((TruthSource(source[0], source[1], 0.0, cps_at_1m),), background,
                  {"dead_time": {"tau_s": tau_s}} if tau_s else {})
    return Dataset(frames=frames, scenario=scen, truth=truth)
