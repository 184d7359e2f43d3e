"""Expected and drawn counts of the 32-channel board for frames at true detector poses.

Per frame (pose p, yaw, mid-time t, duration T) the true rate in channel k is

    n_k = sum_sources S * sum_lines w_l * [1/d^2 * A(theta) * exp(-sum mu_w,l L_w) * exp(-mu_air,l d)] * f_l,k(g(t))
          + B(x, y) * f_bg,k(g(t))

with S = cps_at_1m (paper 003 eq. 1-2: the 1/d^2 law; the efficiency and area are folded into S),
w_l the share of the counts due to line l when facing the source at 1 m, f_l,k the share of line l's
counts in channel k (response.py) at the gain g(t) of the drift effect, A the anisotropy factor,
B(x, y) = B + gx x + gy y the background. Every effect is applied only when enabled in the scene.
The recorded rate is n_k exp(-n tau), n = sum_k n_k (paralyzable dead time, paper 000 eq. 10), and
the counts are Poisson draws of T times that from a seeded generator.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from detector_fw_sim import response, transport
from detector_fw_sim.ladder import drifted_edges
from detector_fw_sim.scene import Scene
from radseek.geometry import wall_arrays
from radseek.topics import N_CHANNELS


@dataclass(frozen=True)
class _SourceTerm:
    position: np.ndarray  # (3,)
    cps_at_1m: float
    weights: np.ndarray  # (K,) share of counts per line at nominal gain, sums to 1
    cdfs: np.ndarray  # (K, n_grid + 1) per-line measured cdf, normalised to 1 count in the channels
    wall_mu: np.ndarray  # (W, K)
    air_mu: np.ndarray  # (K,)


@lru_cache(maxsize=16)
def background_cdf(nuclides: tuple[tuple[str, float], ...], scatter_ratio: float, crystal: response.Crystal,
                   fwhm_at_662: float) -> np.ndarray:
    """Measured cumulative spectrum of the terrestrial background (per incident photon, fine grid).

    Incident photons: the gamma lines of each nuclide (pydecay yields, scaled to the nuclide's share)
    plus ``scatter_ratio`` photons per line photon down-scattered in soil and air, spread flat in
    log E from 30 keV to the line energy (the skyshine/buildup continuum).
    """
    node_e = np.geomspace(30.0, 3000.0, 48)
    node_w = np.zeros_like(node_e)
    lines: dict[float, float] = {}
    total_share = sum(s for _, s in nuclides) or 1.0
    for name, share in nuclides:
        gl = [(e, y) for e, y in response.gamma_lines(name) if e >= 30.0]
        ysum = sum(y for _, y in gl) or 1.0
        for e, y in gl:
            w = share / total_share * y / ysum
            lines[e] = lines.get(e, 0.0) + w
            below = node_e < e
            if below.any():
                node_w[below] += scatter_ratio * w / below.sum()
    dep = np.zeros(len(response.energy_grid()) - 1)
    for e, w in list(lines.items()) + list(zip(node_e, node_w, strict=True)):
        if w > 0:
            dep += w * response.deposit_spectrum(float(e), crystal)
    spec = response.escaped_electrons(dep, crystal) @ response._resolution_matrix(round(fwhm_at_662, 6), 0.5)
    return np.concatenate([[0.0], np.cumsum(spec)])


def _check_frames(poses: np.ndarray, t: np.ndarray, duration: np.ndarray) -> tuple[np.ndarray, ...]:
    """Shapes (N, 4), (N,), (N,), all finite, durations >= 0; a ValueError names the bad argument."""
    poses = np.atleast_2d(np.asarray(poses, dtype=float))
    if poses.ndim != 2 or poses.shape[1] != 4:
        raise ValueError(f"poses must be (N, 4) x, y, z, yaw; got shape {poses.shape}")
    n = len(poses)
    try:
        t = np.broadcast_to(np.asarray(t, dtype=float), (n,))
        duration = np.broadcast_to(np.asarray(duration, dtype=float), (n,))
    except ValueError:
        raise ValueError(f"t and duration must be scalars or have {n} entries (one per pose)") from None
    for name, arr in (("poses", poses), ("t", t), ("duration", duration)):
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"{name} must be finite, got {arr[~np.isfinite(arr)][:3]}")
    if np.any(duration < 0):
        raise ValueError(f"duration must be >= 0, got {duration[duration < 0][:3]}")
    return poses, t, duration


class DetectorEmulator:
    """The board's physics for one scene; ``draw`` uses the generator seeded with ``seed``."""

    def __init__(self, scene: Scene, seed: int | None = None):
        self.scene = scene
        self.rng = np.random.default_rng(seed)
        det = scene.detector
        self.ladder = det.comparator_ladder()
        self.channel_edges_keV: np.ndarray = self.ladder.edges_keV()
        self._walls = wall_arrays([w.to_wall() for w in scene.walls])
        e = scene.effects
        positions = [(np.array(s.position, dtype=float), scene.source_cps_at_1m(i)) for i, s in
                     enumerate(scene.sources)]
        if e.second_source.enabled:
            s2 = e.second_source
            positions.append((np.array([s2.x, s2.y, s2.z]), float(s2.cps_at_1m)))
        lines = response.nuclide_response(scene.nuclide, det.crystal, det.fwhm_at_662, det.backscatter_fraction)
        counted = np.array([r.counted(self.channel_edges_keV) for r in lines])
        yields = np.array([r.photons_per_decay for r in lines])
        keep = counted * yields > 0
        lines = tuple(r for r, k in zip(lines, keep, strict=True) if k)
        counted, yields = counted[keep], yields[keep]
        weights = yields * counted / np.sum(yields * counted)
        cdfs = np.stack([r.cdf / c for r, c in zip(lines, counted, strict=True)])
        energies = [r.energy_keV for r in lines]
        wall_mu = (np.stack([scene.wall_mu_per_m(en) for en in energies], axis=1) if len(scene.walls)
                   else np.zeros((0, len(lines))))
        air_mu = np.array([scene.air_mu_per_m(en) for en in energies])
        self._sources = [_SourceTerm(p, c, weights, cdfs, wall_mu, air_mu) for p, c in positions]
        bg = scene.background
        bg_cdf = background_cdf(tuple(sorted(bg.nuclides.items())), bg.scatter_ratio, det.crystal, det.fwhm_at_662)
        self._bg_cdf = bg_cdf / response.fractions_from_cdf(bg_cdf, self.channel_edges_keV).sum()

    # ---------------------------------------------------------------------------- expectation
    def _edges_at(self, t: np.ndarray) -> np.ndarray:
        gd = self.scene.effects.gain_drift
        pct = gd.percent_per_min if gd.enabled else 0.0
        return drifted_edges(self.channel_edges_keV, t, pct)

    def source_rates(self, poses: np.ndarray, t: np.ndarray) -> np.ndarray:
        """(N, 32) true (before dead time) rates from the sources alone, cps."""
        poses = np.atleast_2d(np.asarray(poses, dtype=float))
        t = np.broadcast_to(np.asarray(t, dtype=float), poses.shape[:1])
        p, yaw = poses[:, :3], poses[:, 3]
        edges = self._edges_at(t)
        eff = self.scene.effects
        out = np.zeros((len(poses), N_CHANNELS))
        for src in self._sources:
            geo = transport.inverse_square(p, src.position)
            if eff.anisotropy.enabled:
                a = eff.anisotropy
                geo = geo * transport.anisotropy_factor(p, yaw, src.position, a.fraction, a.half_angle_deg, a.edge_deg)
            per_line = np.broadcast_to(src.weights, (len(p), len(src.weights))).copy()  # (N, K)
            if eff.wall_attenuation.enabled:
                per_line *= transport.wall_transmission(p, src.position, self._walls, src.wall_mu)
            if eff.air_attenuation.enabled:
                per_line *= transport.air_transmission(p, src.position, src.air_mu)
            for k in range(len(src.weights)):
                out += (src.cps_at_1m * geo * per_line[:, k])[:, None] * response.fractions_from_cdf(
                    src.cdfs[k], edges)
        return out

    def background_rates(self, poses: np.ndarray, t: np.ndarray) -> np.ndarray:
        """(N, 32) true background rates, cps: B (+ gx x + gy y with the gradient effect), never < 0."""
        poses = np.atleast_2d(np.asarray(poses, dtype=float))
        t = np.broadcast_to(np.asarray(t, dtype=float), poses.shape[:1])
        b = np.full(len(poses), self.scene.background.cps)
        g = self.scene.effects.background_gradient
        if g.enabled:
            b = np.maximum(b + g.gx * poses[:, 0] + g.gy * poses[:, 1], 0.0)
        return b[:, None] * response.fractions_from_cdf(self._bg_cdf, self._edges_at(t))

    def true_rates(self, poses: np.ndarray, t: np.ndarray) -> np.ndarray:
        return self.source_rates(poses, t) + self.background_rates(poses, t)

    def expected_counts(self, poses: np.ndarray, t: np.ndarray, duration: np.ndarray) -> np.ndarray:
        """poses (N, 4) TRUE x, y, z, yaw; t (N,) frame-mid times; duration (N,) s -> (N, 32) expected
        recorded counts (after dead time)."""
        poses, t, duration = _check_frames(poses, t, duration)
        n_k = self.true_rates(poses, t)
        dt = self.scene.effects.dead_time
        if dt.enabled:
            n_k = n_k * transport.dead_time(n_k.sum(axis=1), dt.tau_s)[:, None]
        return n_k * duration[:, None]

    # ---------------------------------------------------------------------------- draws
    def draw(self, pose: np.ndarray, t: float, duration: float) -> np.ndarray:
        """(32,) int64 Poisson counts for one frame."""
        lam = self.expected_counts(np.asarray(pose, dtype=float)[None, :], np.array([t]), np.array([duration]))[0]
        return self.rng.poisson(lam).astype(np.int64)

    def draw_many(self, poses: np.ndarray, t: np.ndarray, duration: np.ndarray) -> np.ndarray:
        """(N, 32) int64 Poisson counts for N frames (same generator, so a seed fixes the run)."""
        return self.rng.poisson(self.expected_counts(poses, t, duration)).astype(np.int64)
