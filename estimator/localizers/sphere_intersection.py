"""Sphere-intersection localization with outlier rejection (paper 003, Algorithm 1 and eq. 5).

Each dwell point k gives one averaged, background-subtracted reading lambda_k with Poisson error
sigma_k (:mod:`estimator.dwell_summary`). A source of strength S (``cps_at_1m``) lies on the sphere of
radius ``r_k(S) = sqrt(S / lambda_k)`` around dwell point p_k; for the same S the spheres of all dwell
points meet at the source. Algorithm 1, one iteration:

1-6.  spawn ``n_spheres`` concentric spheres per dwell point (a geometric grid of S) and intersect the
      spheres of equal S of every pair of dwell points. With ``plane=True`` (sources on the floor
      ``scenario.source_z``) each sphere is cut with that plane and the two circles intersect in <= 2
      points; with ``plane=False`` the 3-D intersection circle is discretised into ``n_circle`` points
      and points outside ``scenario.bounds`` are dropped.
7-14. for every intersection point p_j (with its S_j) the expected reading at every dwell point,
      ``S_j / |p_j - p_k|^2``, is scored with the normal PDF N(lambda_k, sigma_k); rho_j is the average.
15.   keep I' = {p_j : rho_j >= alpha max rho}.
16-18. weighted centroid c and std sigma_c of I'; points farther than one sigma_c (per axis) are outliers;
      the centroid p_s of the rest, its std sigma_s and the mean intensity lambda_s are the new estimate.
19.   the estimate is accepted only if it lowers eq. 5, ``eps = 1/k sum_k (lambda_k - lambda_hat(p_s->p_k))^2``,
      against the previous estimate on the same dwell points. The iteration runs after every new dwell
      point once three readings are above background. A new dwell point whose reading disagrees with the
      current estimate by more than ``drop_sigma`` (and, with ``drop_outliers="occluded"``, whose line of
      sight to the estimate crosses a mapped wall) is dropped as uninformative (paper 003 sec. IV-A).
20-21. with ``occupancy`` (an (M, 3) array of occupied-voxel centroids) the estimate snaps to the nearest one.

Uncertainty: ``covariance_`` is diag(sigma_s^2) for the position (paper 003's sigma_s) and the variance
of S over the final set for the intensity; no CRLB (``crlb_ = None``).
"""

from __future__ import annotations

import itertools
from typing import Any

import numpy as np

from estimator.dwell_summary import summarize_dwells
from estimator.localizers.base import Localizer, source_dict
from radseek.count_model import expected_rate
from radseek.dataset import Frames, Scenario
from radseek.geometry import segment_hits_walls

__all__ = ["SphereIntersection", "intersection_points", "eq5_error"]


def _intensity_grid(p: np.ndarray, lam: np.ndarray, z_s: float, bmin: np.ndarray, bmax: np.ndarray,
                    n: int) -> np.ndarray:
    """Geometric grid of candidate S: from the largest lower bound lambda_k h_k^2 to the farthest corner."""
    # a source is at least |z_k - z_s| from dwell point k: S >= lambda_k h_k^2 for every k
    s_min = float(np.max(lam * np.maximum((p[:, 2] - z_s) ** 2, 1e-4)))
    corners = np.array(list(itertools.product(*zip(bmin, bmax, strict=True))))
    corners[:, 2] = z_s
    far = np.max(np.linalg.norm(p[:, None, :] - corners[None], axis=-1), axis=1)
    s_max = float(np.min(lam * far**2))
    s_max = max(s_max, s_min * 1.01)
    return np.geomspace(s_min, s_max, n)


def intersection_points(centers: np.ndarray, lam: np.ndarray, intensities: np.ndarray, z_s: float | None,
                        n_circle: int = 36) -> tuple[np.ndarray, np.ndarray]:
    """Points where spheres of equal intensity around different dwell points meet (Alg. 1 lines 1-6).

    ``centers`` (K, 3) dwell positions, ``lam`` (K,) background-free readings (> 0), ``intensities``
    (G,) candidate S. With ``z_s`` given, spheres are cut with the plane z = z_s first (<= 2 points per
    pair and S); else 3-D circles are discretised into ``n_circle`` points. Returns points (M, 3) and
    their S (M,).
    """
    k = len(centers)
    pairs = np.array(list(itertools.combinations(range(k), 2)), dtype=int).reshape(-1, 2)
    if len(pairs) == 0:
        return np.zeros((0, 3)), np.zeros(0)
    s = np.asarray(intensities, dtype=float)[None, :]  # (1, G)
    r = np.sqrt(s / lam[:, None])  # (K, G)
    i, j = pairs[:, 0], pairs[:, 1]
    if z_s is not None:
        # sphere ∩ plane: circle around (x_k, y_k) of radius sqrt(r^2 - h_k^2)
        h2 = (centers[:, 2] - z_s) ** 2
        rc2 = r**2 - h2[:, None]
        ok_k = rc2 > 0
        rc = np.sqrt(np.clip(rc2, 0, None))
        c1, c2 = centers[i, :2], centers[j, :2]
        a, b = rc[i], rc[j]  # (Pairs, G)
        ok = ok_k[i] & ok_k[j]
        dvec = c2 - c1
        d = np.linalg.norm(dvec, axis=1)[:, None]
        with np.errstate(invalid="ignore", divide="ignore"):
            x = (d**2 + a**2 - b**2) / (2 * d)
            hh = a**2 - x**2
        ok &= (d > 1e-9) & (hh >= 0)
        hh = np.sqrt(np.clip(hh, 0, None))
        u = dvec / np.where(d > 1e-9, d, 1.0)
        v = np.stack([-u[:, 1], u[:, 0]], axis=1)
        base = c1[:, None, :] + x[..., None] * u[:, None, :]
        pts = np.concatenate([base + hh[..., None] * v[:, None, :], base - hh[..., None] * v[:, None, :]], axis=1)
        ss = np.concatenate([np.broadcast_to(s, a.shape)] * 2, axis=1)
        okk = np.concatenate([ok, ok], axis=1)
        pts3 = np.concatenate([pts, np.full(pts.shape[:-1] + (1,), z_s)], axis=-1)
        return pts3[okk], ss[okk]
    # 3-D: circle of the sphere-sphere intersection, discretised
    c1, c2 = centers[i], centers[j]
    a, b = r[i], r[j]
    dvec = c2 - c1
    d = np.linalg.norm(dvec, axis=1)[:, None]
    with np.errstate(invalid="ignore", divide="ignore"):
        x = (d**2 + a**2 - b**2) / (2 * d)
        hh = a**2 - x**2
    ok = (d > 1e-9) & (hh >= 0)
    rad = np.sqrt(np.clip(hh, 0, None))
    u = dvec / np.where(d > 1e-9, d, 1.0)
    helper = np.where(np.abs(u[:, 2:3]) < 0.9, np.array([[0.0, 0.0, 1.0]]), np.array([[1.0, 0.0, 0.0]]))
    e1 = np.cross(u, helper)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(u, e1)
    ang = np.linspace(0, 2 * np.pi, n_circle, endpoint=False)
    ring = (np.cos(ang)[:, None, None, None] * e1[None, :, None, :]
                + np.sin(ang)[:, None, None, None] * e2[None, :, None, :])
    centre = c1[:, None, :] + x[..., None] * u[:, None, :]  # (Pairs, G, 3)
    pts = centre[None] + rad[None, ..., None] * ring  # (A, Pairs, G, 3)
    ss = np.broadcast_to(s, a.shape)[None].repeat(n_circle, axis=0)
    okk = np.broadcast_to(ok[None], pts.shape[:-1])
    return pts[okk], ss[okk]


def eq5_error(position: np.ndarray, intensity: float, centers: np.ndarray, lam: np.ndarray) -> float:
    """Paper 003 eq. 5: mean squared difference of readings and the estimate's expected readings."""
    return float(np.mean((lam - expected_rate(((centers - position) ** 2).sum(axis=1), intensity)) ** 2))


class SphereIntersection(Localizer):
    """Paper 003 Algorithm 1 (see module docstring). Single source; needs >= 3 dwell points above background."""

    name = "sphere"

    def __init__(self, n_spheres: int = 300, n_circle: int = 36, alpha: float = 0.8, plane: bool = True,
                 min_sigma_above_background: float = 3.0, drop_outliers: str = "occluded", drop_sigma: float = 4.0,
                 relative_error: float = 0.05, occupancy: Any = None, min_frames: int = 5):
        self.n_spheres = n_spheres
        self.n_circle = n_circle
        self.alpha = alpha
        self.plane = plane
        self.min_sigma_above_background = min_sigma_above_background
        self.drop_outliers = drop_outliers
        self.drop_sigma = drop_sigma
        self.relative_error = relative_error
        self.occupancy = occupancy
        self.min_frames = min_frames

    # ------------------------------------------------------------------------ one iteration

    def _iterate(self, centers: np.ndarray, lam: np.ndarray, sig: np.ndarray, scenario: Scenario
                 ) -> tuple[np.ndarray, np.ndarray, float, float] | None:
        z_s = scenario.source_z if self.plane else None
        grid = _intensity_grid(centers, lam, scenario.source_z, scenario.bounds_min, scenario.bounds_max,
                               self.n_spheres)
        pts, ss = intersection_points(centers, lam, grid, z_s, self.n_circle)
        axes = 2 if self.plane else 3  # on the floor plane z is fixed; in 3-D the whole box bounds the source
        lo, hi = scenario.bounds_min[:axes] - 1e-9, scenario.bounds_max[:axes] + 1e-9
        inside = np.all((pts[:, :axes] >= lo) & (pts[:, :axes] <= hi), axis=1)
        pts, ss = pts[inside], ss[inside]
        if len(pts) == 0:
            return None
        # lines 7-14: expected reading at every dwell point and its PDF under N(lambda_k, sigma_k)
        expected = expected_rate(((pts[:, None, :] - centers[None]) ** 2).sum(-1), ss[:, None])
        sd = np.sqrt(sig**2 + (self.relative_error * lam) ** 2)
        rho = np.exp(-0.5 * ((expected - lam) / sd) ** 2) / (np.sqrt(2 * np.pi) * sd)
        rho_bar = rho.mean(axis=1)
        # line 15: top subset
        keep = rho_bar >= self.alpha * rho_bar.max()
        p1, s1, w1 = pts[keep], ss[keep], rho_bar[keep]
        # line 16: weighted centroid and std
        c = np.average(p1, axis=0, weights=w1)
        sc = np.sqrt(np.average((p1 - c) ** 2, axis=0, weights=w1))
        # line 17: outliers beyond one std (per axis; axes with no spread never reject)
        inl = np.all((np.abs(p1 - c) <= sc + 1e-9), axis=1)
        if inl.sum() == 0:
            inl[:] = True
        p2, s2, w2 = p1[inl], s1[inl], w1[inl]
        # line 18: centroid, std and mean intensity of the kept set
        ps = np.average(p2, axis=0, weights=w2)
        sig_s = np.sqrt(np.average((p2 - ps) ** 2, axis=0, weights=w2))
        lam_s = float(np.average(s2, weights=w2))
        var_s = float(np.average((s2 - lam_s) ** 2, weights=w2))
        return ps, sig_s, lam_s, var_s

    # ------------------------------------------------------------------------------ fitting

    def _fit(self, frames: Frames, scenario: Scenario) -> None:
        summary = summarize_dwells(frames, min_frames=self.min_frames)
        bg = scenario.background_cps
        lam_all = summary.rate - bg
        sig_all = np.sqrt(summary.rate_sigma**2 + (bg * 0.05 / np.sqrt(3)) ** 2)  # operator bg a few % off
        above = lam_all > self.min_sigma_above_background * sig_all
        centers_all = summary.positions
        used: list[int] = []
        dropped: list[int] = []
        best: tuple[np.ndarray, np.ndarray, float, float] | None = None
        best_eps = np.inf
        history = []
        for k in range(len(summary)):
            if not above[k]:
                continue
            if best is not None and self.drop_outliers != "never":
                # a new dwell that disagrees with the current estimate (paper 003: dropped when occluded)
                pred = float(expected_rate(((centers_all[k] - best[0]) ** 2).sum(), best[2]))
                sd = np.hypot(sig_all[k], self.relative_error * max(pred, lam_all[k]))
                disagrees = abs(lam_all[k] - pred) > self.drop_sigma * sd
                occluded = bool(scenario.walls) and bool(segment_hits_walls(centers_all[k], best[0], scenario.walls))
                if disagrees and (self.drop_outliers == "always" or occluded):
                    dropped.append(k)
                    continue
            used.append(k)
            if len(used) < 3:
                continue
            idx = np.array(used)
            res = self._iterate(centers_all[idx], lam_all[idx], sig_all[idx], scenario)
            if res is None:
                continue
            eps_new = eq5_error(res[0], res[2], centers_all[idx], lam_all[idx])
            eps_old = np.inf if best is None else eq5_error(best[0], best[2], centers_all[idx], lam_all[idx])
            if eps_new <= eps_old:
                best, best_eps = res, eps_new
            history.append({"dwell": int(summary.index[k]), "accepted": bool(eps_new <= eps_old),
                            "eps": float(min(eps_new, eps_old))})
        if best is None:
            raise ValueError(f"sphere intersection needs >= 3 dwell points above background, "
                             f"got {int(above.sum())} of {len(summary)}")
        ps, sig_s, lam_s, var_s = best
        if self.occupancy is not None:
            occ = np.asarray(self.occupancy, dtype=float).reshape(-1, 3)
            if len(occ):
                ps = occ[np.argmin(((occ - ps) ** 2).sum(axis=1))]
        floor = 1e-6
        self.sources_ = [source_dict(ps[0], ps[1], ps[2], lam_s)]
        self.covariance_ = np.diag([sig_s[0] ** 2 + floor, sig_s[1] ** 2 + floor, sig_s[2] ** 2 + floor,
                                    var_s + floor])
        self.background_ = float(bg)
        self.crlb_ = None
        self.info_ = {"eps": best_eps, "dwells_used": [int(summary.index[i]) for i in used],
                      "dwells_dropped": [int(summary.index[i]) for i in dropped], "iterations": history}

