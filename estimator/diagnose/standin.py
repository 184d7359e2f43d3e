"""A small stand-in for ``estimator.model`` / ``estimator.mle`` with the same API.

Used only when the lead's measurement model cannot be imported (so diagnose keeps working and its tests
can run on their own). Physics per dataset-format.md; pose uncertainty is handled by per-dwell position
offsets with a Gaussian prior, optimised alternately with the global parameters.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace

import numpy as np
from scipy import stats

from radseek.dataset import EFFECTS, Frames, Scenario
from radseek.geometry import path_lengths, wall_arrays


@dataclass(frozen=True)
class Param:
    name: str
    value: float
    lower: float
    upper: float
    fixed: bool = False
    unit: str = ""


def _effect_params(effect: str, sc: Scenario) -> list[Param]:
    lo, hi = sc.bounds_min, sc.bounds_max
    cx, cy = ((lo + hi) / 2)[:2]
    table = {
        "dead_time": [Param("dead_time.tau_s", 1e-6, 0.0, 1e-3, unit="s")],
        "wall_attenuation": [Param("wall_attenuation.mu_per_m", 0.5, 0.0, 30.0, unit="1/m")],
        "anisotropy": [Param("anisotropy.fraction", 0.2, 0.0, 1.0), Param("anisotropy.half_angle_deg", 30.0, 5.0,
                       90.0, unit="deg"), Param("anisotropy.edge_deg", 4.0, 0.5, 30.0, fixed=True, unit="deg")],
        "air_attenuation": [Param("air_attenuation.mu_per_m", 0.005, 0.0, 0.5, unit="1/m")],
        "second_source": [Param("second_source.x", cx, lo[0], hi[0], unit="m"),
                          Param("second_source.y", cy, lo[1], hi[1], unit="m"),
                          Param("second_source.z", sc.source_z, lo[2], hi[2], fixed=True, unit="m"),
                          Param("second_source.cps_at_1m", 100.0, 0.0, 1e7, unit="cps")],
        "background_gradient": [Param("background_gradient.gx", 0.0, -100, 100, unit="cps/m"),
                                Param("background_gradient.gy", 0.0, -100, 100, unit="cps/m")],
        "pose_drift": [Param("pose_drift.vx", 0.0, -0.2, 0.2, unit="m/s"),
                       Param("pose_drift.vy", 0.0, -0.2, 0.2, unit="m/s")],
    }
    return table[effect]


class MeasurementModel:
    def __init__(self, scenario: Scenario, effects: tuple[str, ...] = ()):
        for e in effects:
            if e not in EFFECTS or e == "gain_drift":
                raise ValueError(f"unknown or unsupported effect {e!r}")
        self.scenario = scenario
        self.effects = tuple(effects)
        lo, hi = scenario.bounds_min, scenario.bounds_max
        c = (lo + hi) / 2
        ps = [
            Param("x", c[0], lo[0], hi[0], unit="m"),
            Param("y", c[1], lo[1], hi[1], unit="m"),
            Param("z", scenario.source_z, lo[2], hi[2], fixed=True, unit="m"),
            Param("cps_at_1m", 1000.0, 0.0, 1e8, unit="cps"),
            Param("background_cps", max(scenario.background_cps, 1.0), 0.0, 1e5, unit="cps"),
        ]
        for e in self.effects:
            ps += _effect_params(e, scenario)
        self.params = ps
        self._walls = wall_arrays(scenario.walls)

    @property
    def param_names(self) -> list[str]:
        return [p.name for p in self.params]

    def with_effect(self, effect: str) -> MeasurementModel:
        return MeasurementModel(self.scenario, (*self.effects, effect))

    def _theta(self, theta: Mapping[str, float | np.ndarray]) -> dict[str, np.ndarray]:
        out = {}
        for p in self.params:
            v = theta.get(p.name, p.value)
            out[p.name] = np.asarray(v, dtype=float)[..., None] if np.ndim(v) else np.asarray(float(v))
        return out

    def _positions(self, th: dict, frames: Frames, offsets: np.ndarray | None = None) -> np.ndarray:
        pos = frames.positions.copy()
        if offsets is not None:
            pos = pos + offsets
        if "pose_drift" in self.effects:
            vx, vy = th["pose_drift.vx"], th["pose_drift.vy"]
            px = pos[:, 0] - vx * frames.t
            py = pos[:, 1] - vy * frames.t
            return np.stack(np.broadcast_arrays(px, py, pos[:, 2] + 0 * px), axis=-1)
        return pos

    def _one_source(self, th, pos, frames, sx, sy, sz, s):
        dx, dy, dz = sx - pos[..., 0], sy - pos[..., 1], sz - pos[..., 2]
        d2 = np.maximum(dx**2 + dy**2 + dz**2, 1e-4)
        r = s / d2
        if "air_attenuation" in self.effects:
            r = r * np.exp(-th["air_attenuation.mu_per_m"] * np.sqrt(d2))
        if "wall_attenuation" in self.effects and len(self._walls):
            a = pos
            b = np.stack(np.broadcast_arrays(sx + 0 * dx, sy + 0 * dx, sz + 0 * dx), axis=-1)
            r = r * np.exp(-th["wall_attenuation.mu_per_m"] * path_lengths(a, b, self._walls))
        if "anisotropy" in self.effects:
            cy, sy_ = np.cos(frames.yaw), np.sin(frames.yaw)
            cosang = -(cy * dx + sy_ * dy) / np.sqrt(d2)
            theta = np.degrees(np.arccos(np.clip(cosang, -1, 1)))
            red = th["anisotropy.fraction"] * (1 - np.tanh((theta - th["anisotropy.half_angle_deg"])
                                                          / th["anisotropy.edge_deg"])) / 2
            r = r * (1 - red)
        return r

    def source_rate(self, theta, frames: Frames, offsets=None) -> np.ndarray:
        th = self._theta(theta)
        pos = self._positions(th, frames, offsets)
        r = self._one_source(th, pos, frames, th["x"], th["y"], th["z"], th["cps_at_1m"])
        if "second_source" in self.effects:
            r = r + self._one_source(th, pos, frames, th["second_source.x"], th["second_source.y"],
                                     th["second_source.z"], th["second_source.cps_at_1m"])
        return r

    def background_rate(self, theta, frames: Frames, offsets=None) -> np.ndarray:
        th = self._theta(theta)
        b = th["background_cps"] + 0 * frames.t
        if "background_gradient" in self.effects:
            pos = self._positions(th, frames, offsets)
            b = b + th["background_gradient.gx"] * pos[..., 0] + th["background_gradient.gy"] * pos[..., 1]
        return np.maximum(b, 1e-6)

    def expected_counts(self, theta, frames: Frames, offsets=None) -> np.ndarray:
        th = self._theta(theta)
        n = self.source_rate(theta, frames, offsets) + self.background_rate(theta, frames, offsets)
        if "dead_time" in self.effects:
            n = n * np.exp(-n * th["dead_time.tau_s"])
        return n * frames.duration


@dataclass
class FitResult:
    values: dict[str, float]
    errors: dict[str, float]
    covariance: np.ndarray
    free_names: list[str]
    nll: float
    deviance: float
    dof: int
    deviance_per_dof: float
    p_value: float
    expected: np.ndarray
    pose_offsets: np.ndarray
    model: MeasurementModel
    extra: dict = field(default_factory=dict)


def _poisson_nll(mu, n):
    mu = np.maximum(mu, 1e-12)
    return float((mu - n * np.log(mu)).sum())


def _dwell_offsets(model, values, frames, n, offsets):
    """A few damped Newton steps per dwell for the position offset (prior N(0, var)), vectorised over dwells."""
    dw = frames.dwell
    nd = int(dw.max()) + 1 if np.any(dw >= 0) else 0
    if nd == 0:
        return offsets
    var = np.maximum(frames.pose_variances, 1e-8)
    per = np.zeros((nd, 3))
    for k in range(nd):  # one small mean per dwell
        m = dw == k
        if m.any():
            per[k] = var[m].mean(0)
    eps = 1e-3
    cur = np.zeros((nd, 3))
    for k in range(nd):
        m = dw == k
        if m.any():
            cur[k] = offsets[m][0]
    mov = dw >= 0

    def obj(cur):
        off = np.zeros((len(frames), 3))
        off[mov] = cur[dw[mov]]
        mu = model.expected_counts(values, frames, off)
        ll = np.maximum(mu, 1e-12) - n * np.log(np.maximum(mu, 1e-12))
        return np.bincount(dw[mov], weights=ll[mov], minlength=nd) + 0.5 * (cur**2 / per).sum(1)

    for _ in range(4):
        f0 = obj(cur)
        g = np.zeros((nd, 3))
        h = np.zeros((nd, 3))
        for a in range(3):
            e = np.zeros(3)
            e[a] = eps
            fp, fm = obj(cur + e), obj(cur - e)
            g[:, a] = (fp - fm) / (2 * eps)
            h[:, a] = np.maximum((fp - 2 * f0 + fm) / eps**2, 1.0 / per[:, a])
        step = np.clip(-g / h, -0.05, 0.05)
        new = cur + step
        better = obj(new) < f0
        cur = np.where(better[:, None], new, cur)
    off = np.zeros((len(frames), 3))
    off[mov] = cur[dw[mov]]
    return off


def fit(model: MeasurementModel, frames: Frames, n_starts: int = 8, seed: int = 0, pose_uncertainty: bool = True,
        init: Mapping[str, float] | None = None) -> FitResult:
    n = frames.total_counts.astype(float)
    free = [p for p in model.params if not p.fixed]
    names = [p.name for p in free]
    lo = np.array([p.lower for p in free])
    hi = np.array([p.upper for p in free])
    fixed = {p.name: p.value for p in model.params if p.fixed}
    base = {p.name: p.value for p in free}
    rate = n / frames.duration
    base["background_cps"] = max(float(np.quantile(rate, 0.1)), 1.0)
    i = int(np.argmax(rate))
    h = max(frames.z[i] - model.scenario.source_z, 0.3)
    base["cps_at_1m"] = max(float(rate[i] - base["background_cps"]) * h**2, 1.0)
    base["x"], base["y"] = float(np.clip(frames.x[i], lo[0], hi[0])), float(np.clip(frames.y[i], lo[1], hi[1]))
    if init:
        base.update({k: float(v) for k, v in init.items() if k in base})
    rng = np.random.default_rng(seed)
    offsets = np.zeros((len(frames), 3))

    from iminuit import Minuit

    def make(off):
        def f(u):
            th = dict(fixed)
            th.update(dict(zip(names, u, strict=True)))
            return _poisson_nll(model.expected_counts(th, frames, off), n)
        return f

    def run(start, off):
        u0 = np.clip(np.array([start[k] for k in names], dtype=float), lo, hi)
        m = Minuit(make(off), u0, name=names)
        m.errordef = 0.5
        m.limits = list(zip(lo, hi, strict=True))
        m.errors = [max(abs(v) * 0.1, (b - a) * 1e-3, 1e-9) for v, a, b in zip(u0, lo, hi, strict=True)]
        m.strategy = 1
        m.migrad(ncall=4000)
        return m

    starts = [base]
    for _ in range(max(n_starts - 1, 0)):
        s = dict(base)
        for p in free:
            if p.name in ("x", "y", "second_source.x", "second_source.y"):
                s[p.name] = rng.uniform(p.lower, p.upper)
            elif p.name.endswith("cps_at_1m"):
                s[p.name] = base.get(p.name, p.value) * np.exp(rng.normal(0, 1))
        starts.append(s)
    best = min((run(s, offsets) for s in starts), key=lambda r: r.fval)
    if pose_uncertainty and np.any(frames.dwell >= 0):
        for _ in range(2):
            vals = dict(fixed)
            vals.update(dict(zip(names, np.array(best.values), strict=True)))
            offsets = _dwell_offsets(model, vals, frames, n, offsets)
            best = run(dict(zip(names, np.array(best.values), strict=True)), offsets)
    best.hesse()
    values = dict(fixed)
    values.update({k: float(v) for k, v in zip(names, best.values, strict=True)})
    k = len(names)
    cov = np.array(best.covariance) if best.covariance is not None else np.full((k, k), np.nan)
    errors = {nm: float(np.sqrt(max(cov[i, i], 0.0))) for i, nm in enumerate(names)}
    f0 = float(best.fval)
    mu = model.expected_counts(values, frames, offsets)
    from estimator.diagnose.residuals import unit_deviance

    dev = float(unit_deviance(n, mu).sum())
    dof = max(len(n) - k, 1)
    prior = 0.0
    if pose_uncertainty:
        prior = 0.5 * float((offsets[frames.dwell >= 0] ** 2 / np.maximum(frames.pose_variances[frames.dwell >= 0],
                                                                             1e-8)).sum() / 1.0)
    nd = int(frames.dwell.max()) + 1 if np.any(frames.dwell >= 0) else 0
    per_dwell = np.zeros((nd, 3))
    for d in range(nd):
        m = frames.dwell == d
        if m.any():
            per_dwell[d] = offsets[m][0]
    return FitResult(values, errors, cov, names, f0 + prior, dev, dof, dev / dof, float(stats.chi2.sf(dev, dof)),
                     mu, per_dwell, model)


def with_values(model: MeasurementModel, values: Mapping[str, float]) -> MeasurementModel:
    m = MeasurementModel(model.scenario, model.effects)
    m.params = [replace(p, value=float(values.get(p.name, p.value))) for p in m.params]
    return m
