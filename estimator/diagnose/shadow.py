"""Where an unmapped wall would stand: placements of a slab scored by the shadow they would cast.

A wall the map lacks multiplies the source term of every line of sight through it by exp(-mu L) (paper 004
eq. 5.19). With the current fit's source held where it is, each candidate placement (centre on a grid over the
region between the flight and the source, ``N_ANGLES`` orientations, a few lengths) shadows a set of segments
(dwells and 1 s transit pieces, ``residuals.segments``); its Poisson likelihood with the shadowed source term
scaled by exp(-mu L) and the strength rescaled by k (both profiled, mu >= 0 on a grid of mu x thickness) is
compared with the current fit's. The best placements, kept apart, start the full fit (source, wall ends and
mu free, pose offsets profiled: ``estimator.mle.fit``).

The number of placements scored is also the look-elsewhere factor of the wall's test: the wall's position is
not identified when mu = 0 (Davies 1987), and a Bonferroni bound over the placements a search could have picked
is conservative (``selection.null_log10_p``).

Lengths here are those of tall thin slabs (the line of sight crosses the slab's centre line; L = thickness /
|cos| of the angle to the wall's normal, in 3-D): a screen, not the model (``estimator.model.UnmappedWall``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimator.diagnose.residuals import aggregate, group_mean, segments
from estimator.model import UnmappedWall
from radseek.dataset import Frames

N_ANGLES = 12
LENGTHS_M = (1.0, 2.0, 3.5)  # the model's lower bound first (estimator.model.UnmappedWall.MIN_LENGTH_M)
SPACING_M = 0.4
#: mu x thickness values the screen profiles over (dimensionless optical depths)
OPTICAL_DEPTHS = (0.05, 0.1, 0.2, 0.3, 0.5, 0.75, 1.0, 1.5, 2.5)
CHUNK = 1500
#: wall centres screened at most (a wide survey's grid is coarser: its far placements differ little in shadow)
MAX_CENTRES = 1200


@dataclass
class Placements:
    walls: np.ndarray  # (P, 6): x0, y0, x1, y1, thickness, height
    lr: np.ndarray  # (P,) 2 (nll_current - nll_with_wall), source held
    mu_t: np.ndarray  # (P,) best optical depth
    scored: int  # placements considered (the look-elsewhere count)

    def best(self, source_xy: np.ndarray, n: int = 3, apart_m: float = 0.5) -> list[dict[str, float]]:
        """Start values (``unmapped_wall.*``) of the ``n`` best placements whose centres are ``apart_m`` apart."""
        out: list[dict[str, float]] = []
        centres: list[np.ndarray] = []
        self.best_lr: list[float] = []
        for i in np.argsort(-self.lr):
            if self.lr[i] <= 0 or len(out) >= n:
                break
            w = self.walls[i]
            c = (w[0:2] + w[2:4]) / 2
            if all(np.hypot(*(c - o)) > apart_m for o in centres):
                centres.append(c)
                out.append({**UnmappedWall.placement(w, source_xy), "mu_per_m": self.mu_t[i] / w[4]})
                self.best_lr.append(float(self.lr[i]))
        return out


def candidate_walls(lo: np.ndarray, hi: np.ndarray, spacing: float = SPACING_M, n_angles: int = N_ANGLES,
                    lengths: tuple[float, ...] = LENGTHS_M, thickness: float = UnmappedWall.THICKNESS_M,
                    height: float = UnmappedWall.HEIGHT_M) -> np.ndarray:
    """(P, 6) slabs with centres on a grid over [lo, hi] (x-y), every orientation and length."""
    gx = np.arange(lo[0], hi[0] + 1e-9, spacing)
    gy = np.arange(lo[1], hi[1] + 1e-9, spacing)
    cx, cy, ang, ln = (a.ravel() for a in np.meshgrid(gx, gy, np.arange(n_angles) * np.pi / n_angles,
                                                       np.asarray(lengths), indexing="ij"))
    ux, uy = np.cos(ang) * ln / 2, np.sin(ang) * ln / 2
    return np.column_stack([cx - ux, cy - uy, cx + ux, cy + uy, np.full_like(cx, thickness),
                            np.full_like(cx, height)])


def placeable(walls: np.ndarray, source_xy: np.ndarray) -> np.ndarray:
    """(P,) bool: the slabs the effect can take (``UnmappedWall.placement`` is not None), vectorised: the centre at
    least ``MIN_DISTANCE_M`` from the source and the slab within ``MAX_TILT_DEG`` of square to the line source ->
    centre."""
    c = (walls[:, 0:2] + walls[:, 2:4]) / 2
    d = walls[:, 2:4] - walls[:, 0:2]
    rel = c - np.asarray(source_xy, float)[:2]
    phi = np.degrees(np.arctan2(rel[:, 1], rel[:, 0]))
    tilt = (np.degrees(np.arctan2(d[:, 1], d[:, 0])) - phi) % 180.0 - 90.0
    return (np.hypot(rel[:, 0], rel[:, 1]) >= UnmappedWall.MIN_DISTANCE_M) & (np.abs(tilt) <= UnmappedWall.MAX_TILT_DEG)


def thin_slab_lengths(pos: np.ndarray, src: np.ndarray, walls: np.ndarray) -> np.ndarray:
    """(P, J) path lengths of the lines of sight pos_j -> src through tall thin slabs ``walls`` (P, 6)."""
    a, b = pos[None, :, :2], src[None, None, :2]
    s0, s1 = walls[:, None, 0:2], walls[:, None, 2:4]
    r, q = b - a, s1 - s0  # line of sight and wall direction (horizontal)
    den = r[..., 0] * q[..., 1] - r[..., 1] * q[..., 0]
    w = s0 - a
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (w[..., 0] * q[..., 1] - w[..., 1] * q[..., 0]) / den  # along the line of sight
        u = (w[..., 0] * r[..., 1] - w[..., 1] * r[..., 0]) / den  # along the wall
    hit = (np.abs(den) > 1e-12) & (t > 0) & (t < 1) & (u >= 0) & (u <= 1)
    d3 = src[None, None, :] - pos[None, :, :]
    dist = np.linalg.norm(d3, axis=-1)
    qn = np.linalg.norm(q, axis=-1)
    normal = np.stack([-q[..., 1], q[..., 0]], -1) / np.maximum(qn, 1e-12)[..., None]
    cos = np.abs((d3[..., :2] * normal).sum(-1)) / np.maximum(dist, 1e-9)
    thick = walls[:, 4:5]
    length = np.minimum(thick / np.maximum(cos, 1e-3), dist)
    return np.where(hit, length, 0.0)


def score_placements(frames: Frames, expected: np.ndarray, background: np.ndarray, source_xyz: np.ndarray,
                     walls: np.ndarray) -> Placements:
    """LR of each placement against the current fit (``expected`` counts per frame, of which ``background`` is
    not from the source), the source held at ``source_xyz``: the source term of the segments a placement
    shadows is scaled by exp(-mu L), the whole source term by k, both profiled (k by Newton, mu x thickness
    on :data:`OPTICAL_DEPTHS`)."""
    lab = segments(frames, transit_s=1.0)
    n, mu, bg = aggregate(lab, frames.total_counts.astype(float), np.asarray(expected, float),
                          np.asarray(background, float))
    s = np.maximum(mu - bg, 0.0)
    pos = np.column_stack([group_mean(lab, v) for v in (frames.x, frames.y, frames.z)])
    nll0 = float((mu - n * np.log(np.maximum(mu, 1e-300))).sum())
    lr = np.zeros(len(walls))
    best_tau = np.zeros(len(walls))
    taus = np.asarray(OPTICAL_DEPTHS)
    for c0 in range(0, len(walls), CHUNK):
        w = walls[c0:c0 + CHUNK]
        L = thin_slab_lengths(pos, np.asarray(source_xyz, float), w) / w[:, 4:5]  # (P, J) in thicknesses
        # a wall only removes counts: placements whose shadow holds no deficit cannot help
        shadow = L > 0
        deficit = ((n - mu)[None, :] * shadow).sum(1)
        useful = np.flatnonzero(shadow.any(1) & (deficit < 0))
        if len(useful) == 0:
            continue
        T = np.exp(-taus[None, :, None] * L[useful, None, :])  # (p, M, J)
        sT = s[None, None, :] * T
        k = np.ones(sT.shape[:2])
        for _ in range(8):
            m = bg + k[..., None] * sT
            g = ((n / m - 1.0) * sT).sum(-1)
            h = (n / m**2 * sT * sT).sum(-1)
            k = np.clip(k + g / np.maximum(h, 1e-12), 0.2, 5.0)
        m = bg + k[..., None] * sT
        nll = (m - n * np.log(np.maximum(m, 1e-300))).sum(-1)  # (p, M)
        j = np.argmin(nll, axis=1)
        lr[c0 + useful] = 2.0 * (nll0 - nll[np.arange(len(useful)), j])
        best_tau[c0 + useful] = taus[j]
    return Placements(walls, np.maximum(lr, 0.0), best_tau, len(walls))


def screen(frames: Frames, expected: np.ndarray, background: np.ndarray, source_xyz: np.ndarray,
           lo: np.ndarray, hi: np.ndarray, exclude: np.ndarray | None = None) -> Placements:
    """Score every candidate wall between the flight and the source (the box around both, ``lo``/``hi``
    clipped to the scenario bounds grown by the model's margin). ``exclude`` (K, 6): walls already in the model;
    placements crossing them are skipped (a second wall is not the first one again)."""
    pos = frames.positions[:, :2]
    box_lo = np.maximum(np.minimum(pos.min(0), source_xyz[:2]) - 0.5, lo[:2] - UnmappedWall.MARGIN_M)
    box_hi = np.minimum(np.maximum(pos.max(0), source_xyz[:2]) + 0.5, hi[:2] + UnmappedWall.MARGIN_M)
    # a room gets centres SPACING_M apart; a wide survey (100 m) no more than MAX_CENTRES of them
    spacing = max(SPACING_M, float(np.sqrt(np.prod(np.maximum(box_hi - box_lo, 0.0)) / MAX_CENTRES)))
    walls = candidate_walls(box_lo, box_hi, spacing=spacing)
    walls = walls[placeable(walls, source_xyz[:2])]
    if exclude is not None and len(exclude):
        centres = (walls[:, 0:2] + walls[:, 2:4]) / 2
        near = np.zeros(len(walls), dtype=bool)
        for e in exclude:
            c = (e[0:2] + e[2:4]) / 2
            near |= np.hypot(*(centres - c).T) < max(np.hypot(*(e[2:4] - e[0:2])) / 2, 0.5)
        walls = walls[~near]
    return score_placements(frames, expected, background, source_xyz, walls)


def crossings(source_xy: np.ndarray, start: np.ndarray, end: np.ndarray, frames_xy: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray]:
    """Where each frame's line of sight from the source meets the slab's line (``start`` -> ``end``): (s, u), s the
    fraction of the way from the source to the frame, u the fraction along the slab from its start (nan: parallel)."""
    a, b = np.asarray(start, float)[:2], np.asarray(end, float)[:2]
    d = np.asarray(frames_xy, float) - np.asarray(source_xy, float)[:2]
    ab, sa = b - a, a - np.asarray(source_xy, float)[:2]
    cross = d[:, 0] * ab[1] - d[:, 1] * ab[0]
    with np.errstate(divide="ignore", invalid="ignore"):
        cross = np.where(np.abs(cross) > 1e-12, cross, np.nan)
        return (sa[0] * ab[1] - sa[1] * ab[0]) / cross, (sa[0] * d[:, 1] - sa[1] * d[:, 0]) / cross


def seen_part(source_xy: np.ndarray, start: np.ndarray, end: np.ndarray, frames_xy: np.ndarray
              ) -> dict[str, list[float]] | None:
    """The part of a slab that some frame's line of sight from the source crosses (``start``/``end``): the only part
    the counts can locate, since the rest of the slab shades no frame. None if it shades none."""
    s, u = crossings(source_xy, start, end, frames_xy)
    hit = (s > 0) & (s <= 1) & (u >= 0) & (u <= 1)
    if not hit.any():
        return None
    a, b = np.asarray(start, float)[:2], np.asarray(end, float)[:2]
    return {"start": (a + (b - a) * u[hit].min()).tolist(), "end": (a + (b - a) * u[hit].max()).tolist()}
