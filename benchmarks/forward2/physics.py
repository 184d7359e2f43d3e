"""The physics and the recording of the independent forward model (see the package docstring).

Per frame i (10 Hz, duration ~ N(0.1 s, 0.5 ms)) at the TRUE pose:

    source rate  s_ij = S_j / d_ij^2 * exp(-mu_air d_ij) * exp(-mu_wall L_ij) * exp(-mu_u U_ij) * (1 - f cone(theta_ij))
    background   b_i = (B + gx x_i + gy y_i) (1 + a sin(2 pi t_i / T + phi) + r t_i / 6000)
    detected     n_i = sum_j s_ij P_j(a_i) + b_i P_B(a_i)   (P: recorded fraction of a response at gain a_i)

with a_i = 1 + percent_per_min / 100 * t_i / 60. Pulses are drawn event by event (Poisson in time, a
frame-wise gamma factor on the rate when over-dispersed), a paralyzable dead time removes every pulse that
follows the previous pulse (recorded or not) by less than tau, and the surviving pulses of a frame are split
over the 32 channels by the mixture of the source and background channel probabilities. The recorded pose is
the true one plus a per-segment offset and jitter (``pose_error="independent"``) or an odometry random walk in
distance flown (``"random_walk"``), plus ``pose_drift`` v t.

Besides the diagnose vocabulary (dataset-format.md) it makes ``unmapped_wall`` (slabs absent from
scenario.walls; U_ij the path length inside them), a ``second_source`` of another ``nuclide`` (its measured
spectrum), a primary of another nuclide (``FlightSpec.nuclide``), and two effects that vocabulary lacks, to test
an honest "none of these": ``moving_source`` (the primary moves at a constant ``vx``, ``vy`` m/s, from
``start_s`` (or ``start_fraction`` of the flight) on when given, else from t = 0: only then is it not the same
counts as a ``pose_drift``; truth holds its position at t = 0) and ``background_drift`` (``amplitude`` a,
``period_s`` T, ``phase`` phi and ``percent_per_min`` r in the formula above, each optional). Every nuclide is
seen through the flight's ``crystal`` (``fill`` is Cs-137 only: other nuclides then get their measured ``real``
spectrum); the scattered-photon buildup (``scatter``) keeps its Cs-137 continuum whatever the nuclide.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from benchmarks.forward2 import paths as P
from benchmarks.forward2.spectra import (
    EDGES,
    background_response,
    scatter_response,
    source_response,
)
from radseek.dataset import Dataset, Frames, Scenario, Wall
from radseek.truth import Truth, TruthSource

GEOMETRIES = ("lattice", "spin", "lawnmower", "closepass", "outdoor", "wall", "lshape")
#: default primary source strength (cps at 1 m) per geometry
STRENGTH = {"lattice": 2000.0, "spin": 2500.0, "lawnmower": 2000.0, "closepass": 15000.0, "outdoor": 60000.0,
            "wall": 2000.0, "lshape": 2500.0}
FRAME_S = 0.1
OFFSET_H, OFFSET_V, JITTER_H, JITTER_V = 0.04, 0.015, 0.01, 0.005
RW_SD_PER_SQRT_M = 0.02  # odometry random walk (m per sqrt(m) flown), horizontal


@dataclass(frozen=True)
class FlightSpec:
    geometry: str = "lattice"
    effects: dict[str, dict[str, Any]] = field(default_factory=dict)
    crystal: str = "real"
    cps_at_1m: float | None = None
    background_cps: float = 30.0
    pose_error: str = "independent"
    dwell_s: float = 8.0
    #: scattered-photon buildup: a fraction min(scatter * d, 0.5) of a source's counts at distance d is a
    #: down-scattered continuum instead of the crystal's response (the spectrum's shape changes with distance)
    scatter: float = 0.0
    name: str = ""
    #: the primary source's nuclide (Cs-137, Co-60, Eu-152 or Ba-133): its response; scenario.json carries it
    nuclide: str = "Cs-137"
    #: the geometry's walls ("wall", "lshape") are left out of scenario.walls and attenuate as
    #: ``unmapped_wall`` (``effects["unmapped_wall"]["mu_per_m"]`` needed); truth lists them there
    unmap_walls: bool = False


# ------------------------------------------------------------------------------------------- geometry


def slab_lengths(a: np.ndarray, b: np.ndarray, walls: list[Wall]) -> np.ndarray:
    """(N,) total length of the segments a_i -> b inside the wall slabs, by clipping the parametric segment
    against the slab's three pairs of planes in the wall's own frame (along, across, up); ``b`` is one point or
    one per row of ``a``."""
    a = np.atleast_2d(a)
    d = np.atleast_2d(np.asarray(b, dtype=float)) - a  # b: one point (3,) or one per row (N, 3)
    total = np.zeros(len(a))
    for w in walls:
        s0, s1 = np.asarray(w.start, float), np.asarray(w.end, float)
        L = float(np.linalg.norm(s1 - s0))
        u = (s1 - s0) / L
        v = np.array([-u[1], u[0]])
        rel = a[:, :2] - s0
        # coordinates along the wall, across it and up; slab: [0, L] x [-th/2, th/2] x [0, height]
        o = np.column_stack([rel @ u, rel @ v, a[:, 2]])
        dd = np.column_stack([d[:, :2] @ u, d[:, :2] @ v, d[:, 2]])
        lo = np.array([0.0, -w.thickness / 2, 0.0])
        hi = np.array([L, w.thickness / 2, w.height])
        t_in, t_out = np.zeros(len(a)), np.ones(len(a))
        for k in range(3):
            with np.errstate(divide="ignore", invalid="ignore"):
                ta = (lo[k] - o[:, k]) / dd[:, k]
                tb = (hi[k] - o[:, k]) / dd[:, k]
            par = np.abs(dd[:, k]) < 1e-12
            inside = (o[:, k] >= lo[k]) & (o[:, k] <= hi[k])
            t_in = np.where(par, np.where(inside, t_in, 2.0), np.maximum(t_in, np.minimum(ta, tb)))
            t_out = np.where(par, np.where(inside, t_out, -1.0), np.minimum(t_out, np.maximum(ta, tb)))
        total += np.clip(t_out - t_in, 0.0, None) * np.linalg.norm(d, axis=1)
    return total


def back_cone(pos: np.ndarray, yaw: np.ndarray, src: np.ndarray, fraction: float, half_angle_deg: float,
              edge_deg: float) -> np.ndarray:
    """1 - fraction * (1 - tanh((theta - half) / edge)) / 2, theta between the back direction and the source."""
    d = np.atleast_2d(src) - pos
    back = np.column_stack([-np.cos(yaw), -np.sin(yaw), np.zeros_like(yaw)])
    c = np.einsum("ij,ij->i", d, back) / np.maximum(np.linalg.norm(d, axis=1), 1e-9)
    theta = np.degrees(np.arccos(np.clip(c, -1, 1)))
    return 1.0 - fraction * 0.5 * (1.0 - np.tanh((theta - half_angle_deg) / edge_deg))


def source_term(pos: np.ndarray, yaw: np.ndarray, src: np.ndarray, s: float, fx: dict[str, Any],
                mapped: list[Wall], uwalls: list[Wall]) -> tuple[np.ndarray, np.ndarray]:
    """(direct rate (N,), distance (N,)) of a source of ``s`` cps at 1 m at ``src`` (one point or one per frame):
    inverse square, air, mapped walls (``wall_attenuation``), unmapped walls and the back cone."""
    d = np.maximum(np.linalg.norm(pos - src, axis=1), 0.05)
    term = s / d**2
    if "air_attenuation" in fx:
        term = term * np.exp(-fx["air_attenuation"]["mu_per_m"] * d)
    if "wall_attenuation" in fx and mapped:
        term = term * np.exp(-fx["wall_attenuation"]["mu_per_m"] * slab_lengths(pos, src, mapped))
    if uwalls:
        term = term * np.exp(-fx["unmapped_wall"]["mu_per_m"] * slab_lengths(pos, src, uwalls))
    if "anisotropy" in fx:
        a = fx["anisotropy"]
        term = term * back_cone(pos, yaw, src, a["fraction"], a["half_angle_deg"], a.get("edge_deg", 4.0))
    return term, d


def unmapped_walls(fx: dict[str, Any]) -> list[Wall]:
    """The slabs listed in ``fx["unmapped_wall"]["walls"]`` (scenario wall form) as walls, material "unmapped"."""
    out = []
    for w in fx.get("unmapped_wall", {}).get("walls", []):
        out.append(Wall(tuple(map(float, w["start"])), tuple(map(float, w["end"])), float(w["thickness"]),
                        float(w.get("height", 3.0)), str(w.get("material", "unmapped"))))
    return out


def drift_factor(p: dict[str, float], t: np.ndarray) -> np.ndarray:
    """Background multiplier at times t: 1 + amplitude sin(2 pi t / period_s + phase) + percent_per_min t / 6000."""
    f = 1.0 + p.get("percent_per_min", 0.0) / 100.0 * t / 60.0
    if p.get("amplitude", 0.0):
        f = f + p["amplitude"] * np.sin(2 * np.pi * t / p["period_s"] + p.get("phase", 0.0))
    return f


def random_unmapped_wall(spec: FlightSpec, seed: int, mu_t: float, rng: np.random.Generator, n_walls: int = 1
                         ) -> dict[str, Any]:
    """``unmapped_wall`` parameters for ``simulate(spec, seed)``: ``n_walls`` slabs of mu * thickness = ``mu_t``
    (thickness 0.1-0.3 m, height 2-3 m, length 1.5-4 m), each centred 0.6-2.5 m from the source (at most 60 %
    of the way) towards a different waypoint of the flight, its face turned within 45 degrees of square to that
    line of sight, so it shadows part of the flight (waypoints >= 1 rad apart seen from the source, so the
    slabs shade different parts). The scene is rebuilt from ``seed`` as ``simulate`` does."""
    scene, track = _scene(spec, np.random.default_rng(seed))
    src = scene["src"]
    pts = track.points[:, :2]
    dist = np.linalg.norm(pts - src[:2], axis=1)
    cand = np.flatnonzero((dist > 1.6) & (dist < 8.0))
    if not len(cand):
        cand = np.array([int(np.argmax(dist))])
    bearing = np.arctan2(pts[:, 1] - src[1], pts[:, 0] - src[0])
    picks: list[int] = []
    for k in rng.permutation(cand):
        if len(picks) < n_walls and all(abs(np.angle(np.exp(1j * (bearing[k] - bearing[j])))) >= 1.0 for j in picks):
            picks.append(int(k))
    thick = float(rng.uniform(0.1, 0.3))
    walls = []
    for k in picks:
        u = (pts[k] - src[:2]) / dist[k]
        r = float(rng.uniform(0.6, max(0.6, min(2.5, 0.6 * dist[k]))))
        ang = np.arctan2(u[1], u[0]) + np.pi / 2 + rng.uniform(-np.pi / 4, np.pi / 4)
        along = np.array([np.cos(ang), np.sin(ang)])
        half = rng.uniform(1.5, 4.0) / 2
        c = src[:2] + r * u
        walls.append({"start": [float(v) for v in c - half * along], "end": [float(v) for v in c + half * along],
                      "thickness": thick, "height": float(rng.uniform(2.0, 3.0))})
    return {"walls": walls, "mu_per_m": mu_t / thick}


# ------------------------------------------------------------------------------------------- scene


def _scene(spec: FlightSpec, rng: np.random.Generator) -> tuple[dict[str, Any], P.Track]:
    g = spec.geometry
    if g == "outdoor":
        lo, hi = np.array([0.0, 0.0]), np.array([25.0, 25.0])
    elif g == "closepass":
        lo, hi = np.array([0.0, 0.0]), np.array([12.0, 12.0])
    else:
        lo, hi = np.array([0.0, 0.0]), np.array([10.0, 8.0])
    c = (lo + hi) / 2
    src = np.r_[c + rng.uniform(-0.2, 0.2, 2) * (hi - lo), 0.0]
    walls: list[Wall] = []
    far = (float(lo[0] + 0.5), float(lo[1] + 0.5)) if src[0] > c[0] else (float(hi[0] - 0.5), float(hi[1] - 0.5))
    if g in ("lattice", "wall", "lshape"):
        if g == "wall":
            ang = rng.uniform(0, 2 * np.pi)
            n, t = np.array([np.cos(ang), np.sin(ang)]), np.array([-np.sin(ang), np.cos(ang)])
            mid = src[:2] + 0.9 * n
            walls = [Wall(tuple(map(float, mid - 1.6 * t)), tuple(map(float, mid + 1.6 * t)), 0.2, 2.5, "concrete")]
        elif g == "lshape":
            x0, y0 = float(src[0] + 0.7), float(src[1] - 0.7)
            walls = [Wall((x0, y0), (x0, y0 + 2.0), 0.19, 2.0, "cinder block"),
                     Wall((x0 - 2.0, y0), (x0 - 0.095, y0), 0.19, 2.0, "cinder block")]
        track = P.lattice(src, far, rng, n=9 if walls else 8, dwell_s=spec.dwell_s, r=(1.2, 3.5))
    elif g == "spin":
        track = P.lattice(src, far, rng, n=8, alt=1.2, dwell_s=spec.dwell_s, turns=1.0)
    elif g == "lawnmower":
        track = P.lawnmower(tuple(lo + 0.5), tuple(hi - 0.5), rng, spacing=1.5, alt=1.5)
    elif g == "closepass":
        track = P.close_pass(src, rng)
    elif g == "outdoor":
        track = P.lawnmower(tuple(lo), tuple(hi), rng, spacing=2.5, alt=2.0, speed=1.5,
                            end_dwells=[(-40.0, -35.0), (-45.0, 60.0)], dwell_s=12.0)
    else:
        raise ValueError(f"geometry must be one of {GEOMETRIES}, got {g!r}")
    return {"lo": lo, "hi": hi, "src": src, "walls": walls}, track


def simulate(spec: FlightSpec, seed: int = 0) -> Dataset:
    rng = np.random.default_rng(seed)
    scene, track = _scene(spec, rng)
    fx = spec.effects
    mapped = [] if spec.unmap_walls else scene["walls"]
    uwalls = (scene["walls"] if spec.unmap_walls else []) + unmapped_walls(fx)
    if uwalls and "mu_per_m" not in fx.get("unmapped_wall", {}):
        raise ValueError("unmapped walls need effects['unmapped_wall']['mu_per_m']")
    n_max = int(track.duration / FRAME_S) + 10
    dur = np.clip(rng.normal(FRAME_S, 0.0005, n_max), 0.095, 0.105)
    t_end = np.cumsum(dur)
    keep = t_end <= track.duration
    dur, t_end = dur[keep], t_end[keep]
    t_mid = t_end - dur / 2
    pos, yaw, dwell, piece = track.sample(t_mid)

    S = spec.cps_at_1m if spec.cps_at_1m is not None else STRENGTH[spec.geometry]
    src0 = scene["src"]
    src_t = np.broadcast_to(src0, pos.shape)  # the primary's position per frame
    if "moving_source" in fx:
        v = fx["moving_source"]
        # picked up at start_s (or start_fraction of the flight), then carried at v
        t0 = float(v.get("start_s", v.get("start_fraction", 0.0) * track.duration))
        moved = np.maximum(t_mid - t0, 0.0)
        src_t = src0[None, :] + np.column_stack([v["vx"] * moved, v["vy"] * moved, np.zeros_like(t_mid)])
    sources = [(src_t, S, spec.nuclide)]
    if "second_source" in fx:
        p = fx["second_source"]
        sources.append((np.array([p["x"], p["y"], p.get("z", 0.0)]), p["cps_at_1m"],
                        str(p.get("nuclide", spec.nuclide))))
    rates: dict[str, np.ndarray] = {}  # direct source rate per nuclide
    scat = np.zeros(len(t_mid))  # scattered part of the source rate
    for src, s, nuc in sources:
        term, d = source_term(pos, yaw, src, s, fx, mapped, uwalls)
        q = np.minimum(spec.scatter * d, 0.5)
        rates[nuc] = rates.get(nuc, 0.0) + term * (1 - q)
        scat += term * q
    B = spec.background_cps
    rate_b = np.full(len(t_mid), B)
    if "background_gradient" in fx:
        gx, gy = fx["background_gradient"]["gx"], fx["background_gradient"]["gy"]
        rate_b = np.maximum(B + gx * pos[:, 0] + gy * pos[:, 1], 0.1)
    if "background_drift" in fx:
        rate_b = np.maximum(rate_b * drift_factor(fx["background_drift"], t_mid), 0.1)

    # spectra at each frame's gain (frames grouped by gain to 1e-4 to keep this cheap)
    pct = fx.get("gain_drift", {}).get("percent_per_min", 0.0)
    gain = 1.0 + pct / 100.0 * t_mid / 60.0
    q = np.round(gain, 5)
    uq, inv = np.unique(q, return_inverse=True)

    def probs_at_gain(r: Any) -> np.ndarray:
        """(frames, 32) channel probabilities per unit rate (cps_at_1m counts all channels at unit gain)."""
        return r.channel_probs(EDGES, uq)[inv] / r.channel_probs(EDGES, np.ones(1)).sum()

    parts = [probs_at_gain(source_response(spec.crystal if spec.crystal != "fill" or nuc == "Cs-137" else "real",
                                           nuclide=nuc)) * rate[:, None] for nuc, rate in rates.items()]
    parts += [probs_at_gain(background_response()) * rate_b[:, None], probs_at_gain(scatter_response()) * scat[:, None]]
    mix = parts[0]
    for x in parts[1:]:
        mix = mix + x
    n_true = mix.sum(1)
    if "over_dispersion" in fx:
        r = fx["over_dispersion"]["rel_sd"]
        n_true = n_true * rng.gamma(1.0 / r**2, r**2, len(n_true))
    counts_true = rng.poisson(n_true * dur)
    if "dead_time" in fx:
        recorded = _paralyzable(counts_true, t_end - dur, dur, fx["dead_time"]["tau_s"], rng)
    else:
        recorded = counts_true
    probs = mix / np.maximum(mix.sum(1, keepdims=True), 1e-300)
    counts = rng.multinomial(recorded, probs)

    # recorded poses
    rec = pos.copy()
    nseg = int(piece.max()) + 1
    if spec.pose_error == "random_walk":
        step = np.r_[0.0, np.linalg.norm(np.diff(pos[:, :2], axis=0), axis=1)]
        walk = np.cumsum(rng.normal(0.0, 1.0, (len(pos), 2)) * RW_SD_PER_SQRT_M * np.sqrt(step)[:, None], axis=0)
        rec[:, :2] += walk + rng.normal(0, JITTER_H, (len(pos), 2))
        rec[:, 2] += rng.normal(0, JITTER_V, len(pos))
        s_flown = np.cumsum(step)
        var_h = JITTER_H**2 + RW_SD_PER_SQRT_M**2 * s_flown
        var_v = np.full(len(pos), JITTER_V**2)
    elif spec.pose_error == "independent":
        off = np.column_stack([rng.normal(0, OFFSET_H, (nseg, 2)), rng.normal(0, OFFSET_V, nseg)])
        rec += off[piece] + np.column_stack([rng.normal(0, JITTER_H, (len(pos), 2)),
                                             rng.normal(0, JITTER_V, len(pos))])
        var_h = np.full(len(pos), OFFSET_H**2 + JITTER_H**2)
        var_v = np.full(len(pos), OFFSET_V**2 + JITTER_V**2)
    else:
        raise ValueError(f"pose_error must be independent or random_walk, got {spec.pose_error!r}")
    if "pose_drift" in fx:
        rec[:, 0] += fx["pose_drift"]["vx"] * t_mid
        rec[:, 1] += fx["pose_drift"]["vy"] * t_mid
    rec_yaw = (yaw + rng.normal(0, 0.01, len(yaw)) + np.pi) % (2 * np.pi) - np.pi

    frames = Frames(t=t_end, duration=dur, x=rec[:, 0], y=rec[:, 1], z=rec[:, 2], yaw=rec_yaw, var_x=var_h,
                    var_y=var_h.copy(), var_z=var_v, dwell=dwell.astype(int), counts=counts.astype(np.int64))
    lo, hi = scene["lo"], scene["hi"]
    scenario = Scenario(channel_edges_keV=EDGES.copy(), background_cps=float(B * (1 + rng.normal(0, 0.03))),
                        source_z=0.0, bounds_min=np.array([lo[0], lo[1], 0.0]),
                        bounds_max=np.array([hi[0], hi[1], 0.5]), walls=tuple(mapped),
                        nuclide=spec.nuclide)
    effects = {k: dict(v) for k, v in fx.items()}
    if uwalls:
        effects["unmapped_wall"] = {**effects["unmapped_wall"], "walls": [w.to_dict() for w in uwalls]}
    truth = Truth(sources=(TruthSource(float(src0[0]), float(src0[1]), 0.0, float(S), spec.nuclide),),
                  background_cps=B, effects=effects)
    return Dataset(frames=frames, scenario=scenario, truth=truth, path=None)


def _paralyzable(n: np.ndarray, t0: np.ndarray, dur: np.ndarray, tau: float, rng: np.random.Generator
                 ) -> np.ndarray:
    """Recorded pulses per frame: pulses at uniform times within their frames; a pulse is lost when the previous
    pulse (recorded or lost) came less than ``tau`` before it (paralyzable, extending dead time)."""
    frame = np.repeat(np.arange(len(n)), n)
    times = t0[frame] + rng.uniform(0.0, 1.0, len(frame)) * dur[frame]
    order = np.argsort(times, kind="stable")
    times, frame = times[order], frame[order]
    ok = np.r_[True, np.diff(times) > tau]
    return np.bincount(frame[ok], minlength=len(n))
