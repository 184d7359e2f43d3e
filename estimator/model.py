"""The composable measurement model: baseline count model plus any subset of physical effects.

Baseline (paper 003 eq. 1-4; dataset-format.md): the expected counts of a frame of duration T at
detector position p are

    E[counts] = T * ( sum_i S_i / |p - s_i|^2  +  B )

with S_i = ``cps_at_1m`` (paper 003's A e v_s / 4 pi) and B the background rate; each source term and the
dead time come from :func:`radseek.count_model.expected_rate` / ``dead_time``, the one rate law every
localizer and the planner call. Each effect of the vocabulary (``radseek.dataset.EFFECTS``) is a part
with declared parameters and a pure evaluate, in the spirit of astropy.modeling:
``MeasurementModel(scenario, effects=(...))`` composes them and ``with_effect`` adds one, so the
diagnosis can add or drop an effect and refit without rewriting the model. Everything is vectorised over
hypotheses: parameter values may be arrays of shape (P,) (particles, grid cells) and the result is (P, N)
for N frames.

Parameter names: ``x, y, z, cps_at_1m, background_cps`` for the baseline, ``"<effect>.<key>"`` with the
truth.json keys for effects (``dead_time.tau_s``, ``second_source.x`` ...).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from radseek.count_model import MIN_DISTANCE_M, dead_time, expected_rate
from radseek.dataset import EFFECTS, Frames, Scenario
from radseek.geometry import wall_arrays

#: effects that change only the spectrum, not the total counts (see estimator.spectral)
SPECTRAL_ONLY = ("gain_drift",)


@dataclass(frozen=True)
class Param:
    """A model parameter: default (start) value, bounds, whether it is fixed, unit and a fit step."""

    name: str
    value: float
    lower: float
    upper: float
    fixed: bool = False
    unit: str = ""
    step: float = 0.0  # typical scale for the minimiser's first steps (0: 10 % of |value| or 1)

    @property
    def scale(self) -> float:
        return self.step or (0.1 * abs(self.value) if self.value else 1.0)


Theta = Mapping[str, Any]


def _col(v: Any) -> np.ndarray:
    """Hypothesis values (scalar or (P,)) as a column (P, 1) broadcasting against frames (N,)."""
    a = np.asarray(v, dtype=float)
    if a.ndim > 1:
        raise ValueError(f"parameter values must be scalars or 1-D arrays of hypotheses, got shape {a.shape}")
    return a[:, None] if a.ndim else a


# ------------------------------------------------------------------------------------------ effects


@dataclass(frozen=True)
class Context:
    """What an effect may look at: the detector poses used for this evaluation and the scenario."""

    pos: np.ndarray  # (N, 3) detector positions (recorded, or shifted by pose offsets / drift)
    yaw: np.ndarray  # (N,)
    t: np.ndarray  # (N,) frame times
    scenario: Scenario
    walls: np.ndarray  # (W, 6) from radseek.geometry.wall_arrays


class Effect:
    """One physical effect: declared parameters and pure hooks (identity by default)."""

    name: str = ""

    def params(self, scenario: Scenario) -> list[Param]:
        return []

    def positions(self, th: dict[str, np.ndarray], pos: np.ndarray, t: np.ndarray) -> np.ndarray:
        """True detector positions from the recorded ones (pose_drift)."""
        return pos

    def extra_sources(self, th: dict[str, np.ndarray]) -> list[tuple[np.ndarray, ...]]:
        """Additional point sources as (x, y, z, cps_at_1m) columns (second_source)."""
        return []

    def source_factor(self, th: dict[str, np.ndarray], src: np.ndarray, ctx: Context, dist: np.ndarray) -> Any:
        """Multiplicative factor on one source's term; src is (..., 1, 3), dist (..., N)."""
        return 1.0

    def background(self, th: dict[str, np.ndarray], b: np.ndarray, ctx: Context) -> np.ndarray:
        return b

    def recorded_rate(self, th: dict[str, np.ndarray], n: np.ndarray) -> np.ndarray:
        """Recorded rate from the true total rate (dead_time)."""
        return n

    # -- derivatives in the detector's position (MeasurementModel.expected_counts_and_jacobian): an effect that
    # overrides a hook above and not its derivative here makes the model fall back to finite differences

    #: ``positions`` shifts the recorded positions by an amount that does not depend on them (d true / d recorded
    #: is the identity)
    shifts_positions = False
    #: the rate depends on the detector's heading (``ctx.yaw``): frames turning in a spin dwell are not one
    #: hover block (``estimator.mle.hover_blocks``)
    uses_heading = False

    def source_factor_grad(self, th: dict[str, np.ndarray], src: np.ndarray, ctx: Context, dist: np.ndarray
                           ) -> tuple[Any, Any] | None:
        """(factor (N,), d factor / d position (N, 3)) for one scalar hypothesis, or None (not available)."""
        return (1.0, 0.0) if type(self).source_factor is Effect.source_factor else None

    def background_grad(self, th: dict[str, np.ndarray], b: np.ndarray, db: Any, ctx: Context
                        ) -> tuple[np.ndarray, Any] | None:
        """(background, its gradient in the position) from ``b`` and its gradient ``db``, or None."""
        return (b, db) if type(self).background is Effect.background else None

    def prepare_grad(self, th: dict[str, np.ndarray], srcs: list[np.ndarray], ctx: Context) -> None:
        """Called once before :meth:`source_factor_grad` is asked for each of the sources ``srcs`` ((3,) each):
        an effect may compute what they share in one go."""

    def recorded_rate_grad(self, th: dict[str, np.ndarray], n: np.ndarray, dn: np.ndarray
                           ) -> tuple[np.ndarray, np.ndarray] | None:
        """(recorded rate, its gradient) from the true rate ``n`` and its gradient ``dn``, or None."""
        return (n, dn) if type(self).recorded_rate is Effect.recorded_rate else None

    def supports_position_grad(self) -> bool:
        """Every hook this effect overrides has its analytic derivative in the position."""
        return type(self).positions is Effect.positions or self.shifts_positions


class DeadTime(Effect):
    """Paralyzable dead time, paper 000 eq. 10: m = n exp(-n tau) on the total true rate n."""

    name = "dead_time"

    def params(self, scenario: Scenario) -> list[Param]:
        return [Param("dead_time.tau_s", 2e-6, 0.0, 1e-3, unit="s", step=2e-6)]

    def recorded_rate(self, th, n):
        return dead_time(n, th["dead_time.tau_s"])

    def recorded_rate_grad(self, th, n, dn):
        tau = th["dead_time.tau_s"]
        e = np.exp(-n * tau)
        return n * e, (e * (1.0 - n * tau))[:, None] * dn


class WallAttenuation(Effect):
    """Beer-Lambert through the mapped walls: exp(-mu L), L the 3-D path length inside the slabs
    (paper 004 eq. 5.19 with one effective mu for the mapped walls), their edges ramps ``EDGE_M`` wide."""

    name = "wall_attenuation"
    #: path-length cache margin (m): see ``_lengths``
    NEAR_M = 0.5
    #: fewer frames than this skip the near-wall mask: on an in-flight fit's few hundred (pooled) frames the
    #: mask's own evaluation costs more than the lengths it saves
    NEAR_MIN_FRAMES = 2000
    #: m: the walls' edges are ramps this wide (:meth:`_SlabFrame._soft_span`), 0 for hard edges
    EDGE_M = 0.01

    #: path lengths kept for the last few (source, poses) pairs: MIGRAD's gradient steps in the strength,
    #: background and mu (and a profile's first evaluations) ask again for lengths it just computed
    MEMO_SIZE = 8

    def __init__(self) -> None:
        self._near: dict[bytes, tuple[np.ndarray, np.ndarray]] = {}
        self._frame: tuple[bytes, tuple[_SlabFrame, _SlabFrame]] | None = None
        # (source and walls, poses) -> lengths, or (lengths, their gradient) under keys starting b"grad"
        self._memo: dict[tuple[bytes, bytes], Any] = {}

    def params(self, scenario: Scenario) -> list[Param]:
        return [Param("wall_attenuation.mu_per_m", 1.0, 0.0, 100.0, unit="1/m", step=0.5)]

    def source_factor(self, th, src, ctx, dist):
        if ctx.walls.shape[0] == 0:
            return 1.0
        return np.exp(-th["wall_attenuation.mu_per_m"] * self._lengths(ctx.pos, src, ctx.walls))

    def source_factor_grad(self, th, src, ctx, dist):
        if ctx.walls.shape[0] == 0:
            return 1.0, 0.0
        mu = th["wall_attenuation.mu_per_m"]
        lengths, grad = self._lengths_grad(ctx.pos, np.asarray(src, dtype=float).reshape(3), ctx.walls)
        f = np.exp(-mu * lengths)
        return f, (-mu * f)[:, None] * grad

    def _lengths_grad(self, pos: np.ndarray, s: np.ndarray, walls: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`_lengths` of one source (3,) at poses (N, 3) and their gradient in the poses (N, 3)
        (:meth:`_SlabFrame.lengths_grad`), on many frames only where a wall is near (the same mask as
        :meth:`_near_lengths`), the last :data:`MEMO_SIZE` kept."""
        key = (b"grad" + s.tobytes() + walls.tobytes(), np.ascontiguousarray(pos).tobytes())
        out = self._memo.get(key)
        if out is not None:
            return out
        frame = self._slabs(walls)[0]
        near = self._near_mask(pos, s, walls) if len(pos) >= self.NEAR_MIN_FRAMES else None
        if near is None or near.all():
            lengths, grad = frame.lengths_grad(pos, s)
        else:
            lengths, grad = np.zeros(len(pos)), np.zeros((len(pos), 3))
            if near.any():
                lengths[near], grad[near] = frame.lengths_grad(pos[near], s)
        for a in (lengths, grad):
            a.flags.writeable = False
        if len(self._memo) >= self.MEMO_SIZE:
            del self._memo[next(iter(self._memo))]
        self._memo[key] = (lengths, grad)
        return lengths, grad

    def _lengths(self, pos: np.ndarray, src: np.ndarray, walls: np.ndarray) -> np.ndarray:
        """Path lengths (..., N) through the walls with their ramped edges (:meth:`_SlabFrame._soft_span`), computed
        only where they can be non-zero (on ``NEAR_MIN_FRAMES`` or
        more frames; fewer all go through the walls' frames set up once, :class:`_SlabFrame`).

        A fit evaluates one source position at poses that differ by pose offsets and Jacobian steps (a few cm):
        the frames whose line of sight misses every wall grown by ``NEAR_M`` (ends, thickness, top) are found
        once per source position, and while the poses stay within ``NEAR_M / 2`` of those they cannot reach a
        wall (every point of the new segment is within NEAR_M / 2 of the old one), so only the others are
        computed. The last :data:`MEMO_SIZE` results are kept (read-only) for the same source, walls and poses.
        """
        s = np.asarray(src, dtype=float)
        if s.size != 3 or pos.ndim != 2:
            return self._slabs(walls)[0].lengths(pos, s)  # hypotheses (P, 1, 3) or poses (P, N, 3)
        s = s.reshape(3)
        key = (s.tobytes() + walls.tobytes(), np.ascontiguousarray(pos).tobytes())
        out = self._memo.get(key)
        if out is None:
            out = self._near_lengths(pos, s, walls)
            out.flags.writeable = False  # shared by every caller that asks again
            if len(self._memo) >= self.MEMO_SIZE:
                del self._memo[next(iter(self._memo))]
            self._memo[key] = out
        return out

    def _near_lengths(self, pos: np.ndarray, s: np.ndarray, walls: np.ndarray) -> np.ndarray:
        """:meth:`_lengths` computed: all of them, or on many frames only those near a wall."""
        if len(pos) < self.NEAR_MIN_FRAMES:
            return self._slabs(walls)[0].lengths(pos, s)
        near = self._near_mask(pos, s, walls)
        if near.all():
            return self._slabs(walls)[0].lengths(pos, s)
        out = np.zeros(len(pos))
        if near.any():
            out[near] = self._slabs(walls)[0].lengths(pos[near], s)
        return out

    def _near_mask(self, pos: np.ndarray, s: np.ndarray, walls: np.ndarray) -> np.ndarray:
        """(N,) bool: the frames whose line of sight to ``s`` may cross a wall (kept per source position while
        the poses stay within ``NEAR_M / 2`` of those it was computed for)."""
        key = s.tobytes()
        ref = self._near.get(key)
        if ref is None or ref[0].shape != pos.shape or float(np.max(np.linalg.norm(pos - ref[0], axis=1))) > \
                self.NEAR_M / 2:
            if len(self._near) >= 16:
                self._near.clear()
            ref = self._near[key] = (pos.copy(), self._slabs(walls)[1].lengths(pos, s) > 0)
        return ref[1]

    def _slabs(self, walls: np.ndarray) -> tuple[_SlabFrame, _SlabFrame]:
        """The walls' frames and those of the walls grown by ``NEAR_M`` (ends, thickness, top), set up once
        per wall set (the walls of a model never change)."""
        key = walls.tobytes()
        if self._frame is None or self._frame[0] != key:
            m = self.NEAR_M
            grown = walls.copy()
            d = grown[:, 2:4] - grown[:, 0:2]
            u = d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
            grown[:, 0:2] -= m * u
            grown[:, 2:4] += m * u
            grown[:, 4] += 2 * m
            grown[:, 5] += m
            self._frame = (key, (_SlabFrame(walls, self.EDGE_M), _SlabFrame(grown)))
        return self._frame[1]


class _SlabFrame:
    """Path lengths of segments from N detector positions to one source through W vertical slabs, the
    slab method of ``radseek.geometry.path_lengths`` with the walls' frames set up once and every frame's
    local coordinates from one matrix product: the same lengths (to rounding) at a fraction of the
    numpy calls, which is what a fit's thousands of model evaluations on a few hundred frames pay for."""

    def __init__(self, walls: np.ndarray, edge_m: float = 0.0):
        self.edge_m = edge_m
        s0, s1 = walls[:, 0:2], walls[:, 2:4]
        self.length = np.linalg.norm(s1 - s0, axis=1)
        u = (s1 - s0) / np.where(self.length > 0, self.length, 1.0)[:, None]
        v = np.stack([-u[:, 1], u[:, 0]], axis=1)
        self.to_local = np.concatenate([u.T, v.T], axis=1)  # (2, 2W): x-y -> (u_1..u_W, v_1..v_W)
        self.origin = np.concatenate([(s0 * u).sum(1), (s0 * v).sum(1)])  # (2W,)
        self.n = len(walls)
        self.half = walls[:, 4] / 2
        self.height = walls[:, 5]
        self.solid = self.length > 0  # a zero-length wall has no volume

    def lengths(self, pos: np.ndarray, src: np.ndarray) -> np.ndarray:
        """pos (..., N, 3), src (3,) or broadcasting (e.g. (P, 1, 3) hypotheses): (..., N) total length
        inside the slabs."""
        _, _, entries, exits, enter, exit_, seg = self._slab_method(pos, src)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            if self.edge_m > 0:
                span = self._soft_span(entries, exits, enter, exit_, seg)
            else:
                span = np.where(self.solid, np.clip(exit_ - enter, 0.0, None), 0.0)
        return (span * seg).sum(-1)

    def _slab_method(self, pos: np.ndarray, src: np.ndarray) -> tuple[Any, ...]:
        """The slab method's pieces for segments pos (..., N, 3) -> src (..., 1, 3) or (3,): the local
        direction d (..., N, 2W) and its height dz, each axis' entry and exit parameters t, the hard enter / exit
        and the segments' lengths |src - pos| (..., N, W) (the rotation keeps lengths)."""
        w = self.n
        a = pos[..., :2] @ self.to_local - self.origin  # (..., N, 2W)
        d = (src[..., :2] @ self.to_local - self.origin) - a
        az = pos[..., 2:3]
        dz = src[..., 2:3] - az  # (..., N, 1)
        shape = d.shape[:-1] + (w,)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            # a direction with no component along an axis: a huge inverse step keeps it in (or out of) that
            # slab as the explicit parallel case of path_lengths does
            axes = ((a[..., :w], d[..., :w], 0.0, self.length), (a[..., w:], d[..., w:], -self.half, self.half),
                    (az, dz, 0.0, self.height))
            entries, exits = [], []
            for a_k, d_k, lo, hi in axes:
                inv = 1.0 / np.where(d_k == 0, 1e-300, d_k)
                t1, t2 = (lo - a_k) * inv, (hi - a_k) * inv
                entries.append(_broadcast(np.minimum(t1, t2), shape))
                exits.append(_broadcast(np.maximum(t1, t2), shape))
            enter = np.maximum(np.maximum(np.maximum(entries[0], entries[1]), entries[2]), 0.0)
            exit_ = np.minimum(np.minimum(np.minimum(exits[0], exits[1]), exits[2]), 1.0)
            seg = np.sqrt(d[..., :w] ** 2 + d[..., w:] ** 2 + dz**2)
        return d, dz, entries, exits, enter, exit_, seg

    def lengths_grad(self, pos: np.ndarray, src: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """pos (N, 3), src (3,) or one per segment (N, 3): the soft lengths (N,) of :meth:`lengths` (``edge_m``
        > 0) and their analytic gradient in ``pos`` (N, 3).

        Each slab-method parameter t = (c - a) / d along an axis (a the detector's local coordinate, d = s - a
        the segment's) moves as dt/da = (t - 1) / d; the soft max and min are log-sum-exps, whose derivatives are
        their softmax weights (and, in the ramp width eps = edge_m / |d|, (lse - sum w x) / eps); the soft span
        eps softplus(z), z = (out - in) / eps, and the length span |d| follow by the chain rule."""
        if self.edge_m <= 0:
            raise ValueError("lengths_grad needs soft edges (edge_m > 0)")
        w, n = self.n, len(pos)
        shape = (n, w)
        d, dz, entries, exits, enter, exit_, seg = self._slab_method(pos, src)
        eps = self.edge_m / np.maximum(seg, 1e-9)
        near = ((exit_ - enter) > -self._FAR * eps) & self.solid
        if not near.any():
            return np.zeros(n), np.zeros((n, 3))
        rows, cols = np.nonzero(near)
        e, sg = eps[near], seg[near]
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            xin = [x[near] for x in entries]
            xout = [x[near] for x in exits]
            soft_in, w_in, de_in = _soft_max_grad(xin + [np.zeros_like(e)], enter[near], e)
            neg_out, w_out, de_out = _soft_max_grad([-x for x in xout] + [-np.ones_like(e)], -exit_[near], e)
            # the chosen t of an axis moves as (t - 1) / d per unit of its local coordinate a (weight 0: far)
            slope = [np.where(wo > 0, wo * (xo - 1.0), 0.0) - np.where(wi > 0, wi * (xi - 1.0), 0.0)
                     for wi, wo, xi, xo in zip(w_in, w_out, xin, xout, strict=False)]
            r = [np.where(x[near] == 0, 0.0, 1.0 / x[near]) for x in (d[:, :w], d[:, w:], np.broadcast_to(dz, shape))]
        z = (-neg_out - soft_in) / e  # (soft out - soft in) / eps
        softplus = np.maximum(z, 0.0) + np.log1p(np.exp(-np.abs(z)))
        sig = 0.5 * (1.0 + np.tanh(0.5 * z))
        span = e * softplus
        # length = span |d|, span = eps softplus(z): with d eps = -eps / |d| d|d| and d|d| / d pos = (pos - src) / |d|,
        # d length = c_seg (pos - src) / |d| + |d| sig sum_k slope_k r_k d a_k / d pos
        c_seg = span - e * (softplus - z * sig - sig * (de_out + de_in))
        k = sg * sig
        cu, cv, cz = (k * sl * rk for sl, rk in zip(slope, r, strict=True))
        c_seg = c_seg / sg
        lengths = np.bincount(rows, span * sg, minlength=n)
        ux, uy = self.to_local[0, :w][cols], self.to_local[1, :w][cols]
        vx, vy = self.to_local[0, w:][cols], self.to_local[1, w:][cols]
        diff = pos - src
        grad = np.column_stack([
            np.bincount(rows, c_seg * diff[rows, 0] + cu * ux + cv * vx, minlength=n),
            np.bincount(rows, c_seg * diff[rows, 1] + cu * uy + cv * vy, minlength=n),
            np.bincount(rows, c_seg * diff[rows, 2] + cz, minlength=n),
        ])
        return lengths, grad

    def _soft_span(self, entries: list[np.ndarray], exits: list[np.ndarray], enter: np.ndarray, exit_: np.ndarray,
                   seg: np.ndarray) -> np.ndarray:
        """The segment fractions inside the slabs with every max and min of the slab method (``enter``,
        ``exit_`` are the hard ones) made smooth over ``edge_m`` of path (log-sum-exp; a segment's parameter t
        runs over its length, so the scale in t is edge_m / |d|): the length is then differentiable in the
        detector's position, and a shadow edge is a ramp of about ``edge_m`` instead of a kink. Segments that
        pass more than ``_FAR`` ramp widths from a slab get 0 (the soft length there is below 1e-13 edge_m)."""
        eps = self.edge_m / np.maximum(seg, 1e-9)
        near = ((exit_ - enter) > -self._FAR * eps) & self.solid
        span = np.zeros_like(seg)
        if near.any():
            e = eps[near]
            soft_in = _soft_max([x[near] for x in entries] + [np.zeros_like(e)], enter[near], e)
            soft_out = -_soft_max([-x[near] for x in exits] + [-np.ones_like(e)], -exit_[near], e)
            z = (soft_out - soft_in) / e
            span[near] = e * (np.maximum(z, 0.0) + np.log1p(np.exp(-np.abs(z))))
        return span

    #: ramp widths beyond which a segment's soft length through a slab is taken as 0
    _FAR = 30.0


def _broadcast(x: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """``x`` broadcast to ``shape``: itself when it has that shape already (one slab and one source, every call of
    a fit: np.broadcast_to's own cost was 6 % of a profiled likelihood call)."""
    return x if x.shape == shape else np.broadcast_to(x, shape)


def _soft_max(values: list[np.ndarray], top: np.ndarray, eps: np.ndarray) -> np.ndarray:
    """eps log sum exp(v / eps), computed from the largest value ``top`` (no overflow)."""
    acc = np.zeros_like(top)
    for v in values:
        acc += np.exp((v - top) / eps)
    return top + eps * np.log(acc)


def _soft_max_grad(values: list[np.ndarray], top: np.ndarray, eps: np.ndarray
                   ) -> tuple[np.ndarray, list[np.ndarray], np.ndarray]:
    """:func:`_soft_max` with its softmax weights (d value / d v_j) and d value / d eps = (value - sum w v) / eps."""
    ex = [np.exp((v - top) / eps) for v in values]
    acc = ex[0].copy()
    for x in ex[1:]:
        acc += x
    weights = [x / acc for x in ex]
    value = top + eps * np.log(acc)
    mean = np.zeros_like(top)
    for wt, v in zip(weights, values, strict=True):
        mean += np.where(wt > 0, wt * v, 0.0)
    return value, weights, (value - mean) / eps


class UnmappedWall(Effect):
    """A slab the map lacks: Beer-Lambert exp(-mu L) through one vertical slab whose placement is free (paper 004
    eq. 5.19 with the wall's geometry unknown), seen from the (primary) source: its centre ``r`` m away in the
    direction ``phi_deg``, turned ``tilt_deg`` from square to that direction, ``length`` long.

    The slab is ``thickness`` thick (fixed: only mu x thickness is identified by a thin slab's shadow) and
    ``height`` tall (fixed: a flight below the wall's top cannot see it); its edges are ramps ``EDGE_M`` wide so
    that the likelihood is smooth in the placement. A point source's shadow fixes the sector the wall blocks,
    not its distance from the source (a wall twice as far and twice as long casts the same shadow); the length
    is bounded (``MIN_LENGTH_M`` to ``MAX_LENGTH_M``: real obstacles, walls, shelves, vehicles) and the centre
    kept ``MIN_DISTANCE_M`` from the source; the rest of that degeneracy shows in the reported uncertainties."""

    name = "unmapped_wall"
    #: m: the shadow's edges are ramps this wide, so MIGRAD can move the placement
    EDGE_M = 0.08
    THICKNESS_M = 0.2
    HEIGHT_M = 3.0
    MIN_LENGTH_M = 1.0
    #: m: beyond the flown lines of sight a wall's length is not seen; the longest slab the effect places
    MAX_LENGTH_M = 8.0
    #: m: the wall's centre is at least this far from the source (a source inside a slab shields itself, which
    #: is not a wall's shadow)
    MIN_DISTANCE_M = 0.4
    #: deg: the wall's direction turns at most this far from square to the line source -> wall centre
    MAX_TILT_DEG = 75.0
    #: m: the screen looks for walls this far beyond the flight and the source
    MARGIN_M = 3.0
    #: lengths memoised for the last few (placement, source, poses): MIGRAD's steps in strength, background and
    #: mu ask again for lengths it just computed
    MEMO_SIZE = 8

    def __init__(self) -> None:
        self._memo: dict[bytes, Any] = {}  # lengths, or (lengths, gradient) under keys starting b"grad"
        self._frame: tuple[bytes, _SlabFrame] | None = None

    def params(self, scenario: Scenario) -> list[Param]:
        p = self.name
        return [
            Param(f"{p}.r", 1.0, self.MIN_DISTANCE_M, 30.0, unit="m", step=0.2),
            Param(f"{p}.phi_deg", 0.0, -400.0, 400.0, unit="deg", step=10.0),
            Param(f"{p}.tilt_deg", 0.0, -self.MAX_TILT_DEG, self.MAX_TILT_DEG, unit="deg", step=10.0),
            Param(f"{p}.length", 2.0, self.MIN_LENGTH_M, self.MAX_LENGTH_M, unit="m", step=0.3),
            Param(f"{p}.thickness", self.THICKNESS_M, 0.01, 2.0, fixed=True, unit="m", step=0.05),
            Param(f"{p}.height", self.HEIGHT_M, 0.1, 100.0, fixed=True, unit="m", step=0.5),
            Param(f"{p}.mu_per_m", 2.0, 0.0, 100.0, unit="1/m", step=0.5),
        ]

    @classmethod
    def wall_of(cls, values: Mapping[str, Any], name: str | None = None) -> np.ndarray:
        """(6,) slab (x0, y0, x1, y1, thickness, height) from the parameter values (the source's ``x``, ``y``
        among them)."""
        p = name or cls.name
        v = {k: float(np.ravel(values[k])[0]) for k in ("x", "y")}
        v.update({k: float(np.ravel(values[f"{p}.{k}"])[0]) for k in ("r", "phi_deg", "tilt_deg", "length",
                                                                      "thickness", "height")})
        phi = np.radians(v["phi_deg"])
        c = np.array([v["x"], v["y"]]) + v["r"] * np.array([np.cos(phi), np.sin(phi)])
        a = phi + np.pi / 2 + np.radians(v["tilt_deg"])
        h = v["length"] / 2 * np.array([np.cos(a), np.sin(a)])
        return np.array([*(c - h), *(c + h), v["thickness"], v["height"]])

    @classmethod
    def placement(cls, wall: np.ndarray, source_xy: np.ndarray) -> dict[str, float] | None:
        """The effect's parameters (r, phi_deg, tilt_deg, length) of a slab (x0, y0, x1, y1, ...) seen from the
        source, or None when the slab is outside the effect's range (too near the source, too oblique)."""
        c = (wall[0:2] + wall[2:4]) / 2
        d = wall[2:4] - wall[0:2]
        rel = c - np.asarray(source_xy, float)[:2]
        r = float(np.hypot(*rel))
        phi = float(np.degrees(np.arctan2(rel[1], rel[0])))
        tilt = (float(np.degrees(np.arctan2(d[1], d[0]))) - phi - 90.0 + 90.0) % 180.0 - 90.0
        if r < cls.MIN_DISTANCE_M or abs(tilt) > cls.MAX_TILT_DEG:
            return None
        return {"r": r, "phi_deg": phi, "tilt_deg": tilt, "length": float(np.hypot(*d))}

    def _slab(self, wall: np.ndarray) -> _SlabFrame:
        """The slab's frame, set up once per placement (every source and pose of an evaluation shares it)."""
        key = wall.tobytes()
        if self._frame is None or self._frame[0] != key:
            self._frame = (key, _SlabFrame(wall[None, :], self.EDGE_M))
        return self._frame[1]

    def source_factor(self, th, src, ctx, dist):
        p = self.name
        if any(np.size(th[k]) != 1 for k in ("x", "y", f"{p}.r", f"{p}.phi_deg", f"{p}.tilt_deg", f"{p}.length")):
            raise ValueError(f"{p}: the wall's placement must be scalar (one hypothesis at a time)")
        wall = self.wall_of(th, p)
        s = np.asarray(src, dtype=float)
        lengths = self._memoised(b"", wall, s, ctx.pos, lambda: self._slab(wall).lengths(ctx.pos, s))
        return np.exp(-th[f"{p}.mu_per_m"] * lengths)

    @staticmethod
    def _memo_key(kind: bytes, wall: np.ndarray, s: np.ndarray, pos: np.ndarray) -> bytes:
        return kind + wall.tobytes() + s.tobytes() + np.ascontiguousarray(pos).tobytes()

    def _memoised(self, kind: bytes, wall: np.ndarray, s: np.ndarray, pos: np.ndarray, compute: Any) -> Any:
        """``compute()`` for this wall, source and poses, kept in the bounded memo (oldest out first)."""
        key = self._memo_key(kind, wall, s, pos)
        hit = self._memo.get(key)
        if hit is None:
            hit = compute()
            if len(self._memo) >= self.MEMO_SIZE:
                del self._memo[next(iter(self._memo))]
            self._memo[key] = hit
        return hit

    def prepare_grad(self, th, srcs, ctx):
        """The slab lengths and their gradients for every source's lines of sight from one slab-method pass over
        all of them (a second source's lines of sight are the same poses to another point: half the numpy calls
        of two passes, which is what a two-source walled fit pays for), memoised for :meth:`source_factor_grad`."""
        wall = self.wall_of(th, self.name)
        pos = np.ascontiguousarray(ctx.pos)
        srcs = [np.asarray(s, dtype=float).reshape(3) for s in srcs]
        if all(self._memo_key(b"grad", wall, s, pos) in self._memo for s in srcs):
            return
        n = len(pos)
        lengths, grad = self._slab(wall).lengths_grad(np.tile(pos, (len(srcs), 1)), np.repeat(np.asarray(srcs), n, 0))
        for k, s in enumerate(srcs):
            self._memoised(b"grad", wall, s, pos, lambda k=k: (lengths[k * n:(k + 1) * n], grad[k * n:(k + 1) * n]))

    def source_factor_grad(self, th, src, ctx, dist):
        p = self.name
        wall = self.wall_of(th, p)
        s = np.asarray(src, dtype=float).reshape(3)
        lengths, grad = self._memoised(b"grad", wall, s, ctx.pos, lambda: self._slab(wall).lengths_grad(ctx.pos, s))
        mu = th[f"{p}.mu_per_m"]
        f = np.exp(-mu * lengths)
        return f, (-mu * f)[:, None] * grad


class UnmappedWall2(UnmappedWall):
    """A second unmapped slab, offered once the first is in the model (stepwise)."""

    name = "unmapped_wall_2"


class Anisotropy(Effect):
    """Reduced sensitivity in a cone behind the detector (paper 003 calibration, ~50 %):
    factor 1 - f (1 - tanh((theta - half_angle) / edge)) / 2, theta the angle between the detector's
    back direction (-axis, horizontal) and the 3-D direction to the source."""

    name = "anisotropy"
    uses_heading = True

    def params(self, scenario: Scenario) -> list[Param]:
        return [
            Param("anisotropy.fraction", 0.3, 0.0, 1.0, step=0.05),
            Param("anisotropy.half_angle_deg", 40.0, 5.0, 90.0, unit="deg", step=5.0),
            Param("anisotropy.edge_deg", 4.0, 0.5, 30.0, fixed=True, unit="deg", step=1.0),
        ]

    def source_factor(self, th, src, ctx, dist):
        d = src - ctx.pos  # (..., N, 3)
        back = np.stack([-np.cos(ctx.yaw), -np.sin(ctx.yaw)], axis=-1)  # (N, 2)
        cos_t = (d[..., 0] * back[:, 0] + d[..., 1] * back[:, 1]) / np.maximum(dist, 1e-9)
        theta = np.degrees(np.arccos(np.clip(cos_t, -1.0, 1.0)))
        edge = th["anisotropy.edge_deg"]
        cone = 0.5 * (1.0 - np.tanh((theta - th["anisotropy.half_angle_deg"]) / edge))
        return 1.0 - th["anisotropy.fraction"] * cone

    def source_factor_grad(self, th, src, ctx, dist):
        d = src - ctx.pos  # (N, 3)
        back = np.column_stack([-np.cos(ctx.yaw), -np.sin(ctx.yaw), np.zeros(len(ctx.yaw))])  # (N, 3)
        r = np.maximum(dist, 1e-9)
        cos_t = (d * back).sum(-1) / r
        theta = np.degrees(np.arccos(np.clip(cos_t, -1.0, 1.0)))
        edge = th["anisotropy.edge_deg"]
        tanh = np.tanh((theta - th["anisotropy.half_angle_deg"]) / edge)
        cone = 0.5 * (1.0 - tanh)
        # d dist / d pos = -d / dist where dist is not clamped; d cos / d pos = -back / r - cos d(dist) / r
        ddist = np.where((np.sqrt((d**2).sum(-1)) > MIN_DISTANCE_M)[:, None], -d / r[:, None], 0.0)
        dcos = (-back - cos_t[:, None] * ddist) / r[:, None]
        inside = np.abs(cos_t) < 1.0
        dtheta = np.where(inside, -np.degrees(1.0) / np.sqrt(np.maximum(1.0 - cos_t**2, 1e-300)), 0.0)
        dcone = (-0.5 * (1.0 - tanh**2) / edge * dtheta)[:, None] * dcos
        return 1.0 - th["anisotropy.fraction"] * cone, -th["anisotropy.fraction"] * dcone


class AirAttenuation(Effect):
    """Attenuation in air along the whole line of sight: exp(-mu d) (~0.0093 /m at 662 keV)."""

    name = "air_attenuation"

    def params(self, scenario: Scenario) -> list[Param]:
        return [Param("air_attenuation.mu_per_m", 0.005, 0.0, 0.5, unit="1/m", step=0.003)]

    def source_factor(self, th, src, ctx, dist):
        return np.exp(-th["air_attenuation.mu_per_m"] * dist)

    def source_factor_grad(self, th, src, ctx, dist):
        mu = th["air_attenuation.mu_per_m"]
        f = np.exp(-mu * dist)
        diff = ctx.pos - src
        ddist = np.where((dist > MIN_DISTANCE_M)[:, None], diff / np.maximum(dist, 1e-12)[:, None], 0.0)
        return f, (-mu * f)[:, None] * ddist


class SecondSource(Effect):
    """Another point source of the same nuclide (paper 004's multiple landmarks)."""

    name = "second_source"

    def params(self, scenario: Scenario) -> list[Param]:
        lo, hi = scenario.bounds_min, scenario.bounds_max
        c = (lo + hi) / 2
        return [
            Param("second_source.x", float(c[0]), float(lo[0]), float(hi[0]), unit="m", step=0.3),
            Param("second_source.y", float(c[1]), float(lo[1]), float(hi[1]), unit="m", step=0.3),
            Param("second_source.z", scenario.source_z, float(lo[2]), float(hi[2]), fixed=True, unit="m", step=0.1),
            Param("second_source.cps_at_1m", 500.0, 0.0, 1e7, unit="cps", step=100.0),
        ]

    def extra_sources(self, th):
        return [tuple(th[f"second_source.{k}"] for k in ("x", "y", "z", "cps_at_1m"))]


class BackgroundGradient(Effect):
    """Background varying linearly in space: B(x, y) = B + gx x + gy y (B is the rate at the origin)."""

    name = "background_gradient"

    def params(self, scenario: Scenario) -> list[Param]:
        return [
            Param("background_gradient.gx", 0.0, -1e3, 1e3, unit="cps/m", step=0.5),
            Param("background_gradient.gy", 0.0, -1e3, 1e3, unit="cps/m", step=0.5),
        ]

    def background(self, th, b, ctx):
        x, y = ctx.pos[..., 0], ctx.pos[..., 1]
        return np.maximum(b + th["background_gradient.gx"] * x + th["background_gradient.gy"] * y, 1e-3)

    def background_grad(self, th, b, db, ctx):
        gx, gy = th["background_gradient.gx"], th["background_gradient.gy"]
        raw = b + gx * ctx.pos[:, 0] + gy * ctx.pos[:, 1]
        g = db + np.array([float(gx), float(gy), 0.0])
        return np.maximum(raw, 1e-3), np.where((raw > 1e-3)[:, None], g, 0.0)


class PoseDrift(Effect):
    """Odometry drift: recorded = true + v t, so the true position is recorded - v t."""

    name = "pose_drift"
    shifts_positions = True  # recorded - v t: the shift does not depend on the recorded position

    def params(self, scenario: Scenario) -> list[Param]:
        return [
            Param("pose_drift.vx", 0.0, -0.2, 0.2, unit="m/s", step=2e-4),
            Param("pose_drift.vy", 0.0, -0.2, 0.2, unit="m/s", step=2e-4),
        ]

    def positions(self, th, pos, t):
        sx, sy = np.broadcast_arrays(th["pose_drift.vx"] * t, th["pose_drift.vy"] * t)
        return pos - np.stack([sx, sy, np.zeros_like(sx)], axis=-1)


class SourceMotion(Effect):
    """The source moving against the recorded path from a time ``t0`` on, at a constant velocity: the detector's
    position relative to the source is recorded - v max(t - t0, 0). Off the dataset spec's list (a source carried
    off mid-flight), so never a candidate of the selection: the diagnose evaluation fits it, ``t0`` fixed at the
    truth's, to measure whether a moved source is told apart from the effects diagnose named by the counts at all
    (``benchmarks.diagnose_evaluate.truth_model_gap``)."""

    name = "source_motion"
    shifts_positions = True  # recorded - v max(t - t0, 0): the shift does not depend on the recorded position

    def params(self, scenario: Scenario) -> list[Param]:
        return [
            Param("source_motion.vx", 0.0, -2.0, 2.0, unit="m/s", step=2e-3),
            Param("source_motion.vy", 0.0, -2.0, 2.0, unit="m/s", step=2e-3),
            Param("source_motion.t0", 0.0, 0.0, 1e7, fixed=True, unit="s"),
        ]

    def positions(self, th, pos, t):
        dt = np.maximum(t - th["source_motion.t0"], 0.0)
        sx, sy = np.broadcast_arrays(th["source_motion.vx"] * dt, th["source_motion.vy"] * dt)
        return pos - np.stack([sx, sy, np.zeros_like(sx)], axis=-1)


class BackgroundDrift(Effect):
    """A background varying in time: B (1 + amplitude sin(2 pi t / period_s + phase) + percent_per_min t / 6000).
    Off the dataset spec's list, never a candidate: the diagnose evaluation fits it with the truth's period and
    phase to measure whether the counts tell a drifting background from the effects diagnose named
    (``benchmarks.diagnose_evaluate.truth_model_gap``)."""

    name = "background_drift"

    def params(self, scenario: Scenario) -> list[Param]:
        return [
            Param("background_drift.amplitude", 0.0, -1.0, 1.0, step=0.02),
            Param("background_drift.percent_per_min", 0.0, -200.0, 200.0, step=1.0),
            Param("background_drift.period_s", 60.0, 1.0, 1e5, fixed=True, unit="s"),
            Param("background_drift.phase", 0.0, -10.0, 10.0, fixed=True),
        ]

    @staticmethod
    def _factor(th, t):
        return (1.0 + th["background_drift.percent_per_min"] * t / 6000.0
                + th["background_drift.amplitude"] * np.sin(2 * np.pi * t / th["background_drift.period_s"]
                                                           + th["background_drift.phase"]))

    def background(self, th, b, ctx):
        return np.maximum(b * self._factor(th, ctx.t), 1e-3)

    def background_grad(self, th, b, db, ctx):
        f = np.ravel(self._factor(th, ctx.t))
        raw = b * f
        return np.maximum(raw, 1e-3), np.where((raw > 1e-3)[:, None], np.asarray(db) * f[:, None], 0.0)


EFFECT_PARTS: dict[str, type[Effect]] = {
    cls.name: cls
    for cls in (DeadTime, WallAttenuation, UnmappedWall, UnmappedWall2, Anisotropy, AirAttenuation, SecondSource,
                BackgroundGradient, PoseDrift, SourceMotion, BackgroundDrift)
}
#: effects beyond the dataset spec's base table (EFFECTS, which the emulator's scenes mirror): a wall the map
#: lacks (the spec's ``unmapped_wall``; ``unmapped_wall_2`` is a second one, reported under the same name)
OPEN_WORLD_EFFECTS = ("unmapped_wall", "unmapped_wall_2")
#: every count-model effect, in the order models and fits are keyed by
COUNT_EFFECTS: tuple[str, ...] = tuple(EFFECT_PARTS)
#: count-model parts the selection never offers (off the spec's list: see SourceMotion, BackgroundDrift)
UNOFFERED_EFFECTS = ("source_motion", "background_drift")
assert set(EFFECT_PARTS) | set(SPECTRAL_ONLY) == set(EFFECTS) | set(OPEN_WORLD_EFFECTS) | set(UNOFFERED_EFFECTS)


# ------------------------------------------------------------------------------------------ model


class MeasurementModel:
    """Baseline count model composed with effects; pure and vectorised over hypotheses."""

    def __init__(self, scenario: Scenario, effects: Sequence[str] = (), channels: Sequence[int] | None = None):
        for name in effects:
            if name in SPECTRAL_ONLY:
                raise ValueError(f"{name} changes only the spectrum, not total counts: use estimator.spectral")
            if name not in EFFECT_PARTS:
                raise ValueError(f"unknown effect {name!r}; known: {', '.join(sorted(EFFECT_PARTS))}")
        self.scenario = scenario
        # the operator's air (scenario ``air_mu_per_m``) is known physics, not an effect to fit: every
        # model of the scenario attenuates by it, fixed, unless the caller fits air_attenuation itself
        known_air = scenario.air_mu_per_m > 0 and "air_attenuation" not in effects
        self.effects: tuple[str, ...] = tuple(dict.fromkeys((*effects, "air_attenuation") if known_air else effects))
        if channels is not None:
            channels = tuple(sorted({int(k) for k in channels}))
            if not channels or channels[0] < 0 or channels[-1] >= len(scenario.channel_edges_keV) - 1:
                raise ValueError(f"channels must be comparator channels 0..31, got {channels}")
        self.channels: tuple[int, ...] | None = channels
        self._parts = [EFFECT_PARTS[n]() for n in self.effects]
        self._walls = wall_arrays(scenario.walls)
        lo, hi = scenario.bounds_min, scenario.bounds_max
        c = (lo + hi) / 2
        base = [
            Param("x", float(c[0]), float(lo[0]), float(hi[0]), unit="m", step=0.3),
            Param("y", float(c[1]), float(lo[1]), float(hi[1]), unit="m", step=0.3),
            Param("z", scenario.source_z, float(lo[2]), float(hi[2]), fixed=True, unit="m", step=0.1),
            Param("cps_at_1m", 1000.0, 0.0, 1e7, unit="cps", step=100.0),
            Param("background_cps", max(scenario.background_cps, 1.0), 0.0, 1e5, unit="cps", step=2.0),
        ]
        self.params: list[Param] = base + [p for part in self._parts for p in part.params(scenario)]
        if known_air:
            self.params = [replace(p, value=scenario.air_mu_per_m, fixed=True) if p.name == "air_attenuation.mu_per_m"
                           else p for p in self.params]

    @property
    def uses_heading(self) -> bool:
        """Some effect's rate depends on the detector's heading (anisotropy)."""
        return any(part.uses_heading for part in self._parts)

    def __repr__(self) -> str:
        window = "" if self.channels is None else f", channels={list(self.channels)}"
        return f"MeasurementModel(effects={list(self.effects)}{window})"

    def observed_counts(self, frames: Frames) -> np.ndarray:
        """The counts this model explains: all 32 channels summed, or only the chosen window.

        With a window (e.g. the Cs-137 photopeak), ``cps_at_1m`` and ``background_cps`` are the window's
        rates; scattered photons (walls, air, the floor) leave the photopeak, so a peak window is less
        biased by scatter than the total. Dead time still acts on the window by the factor of the total
        true rate, which the window model approximates by its own rate (a lower bound on the loss).
        """
        if self.channels is None:
            return frames.total_counts
        return frames.counts[:, list(self.channels)].sum(axis=1)

    @staticmethod
    def window_channels(scenario: Scenario, lo_keV: float, hi_keV: float) -> tuple[int, ...]:
        """Comparator channels overlapping the energy window [lo_keV, hi_keV)."""
        e = scenario.channel_edges_keV
        k = np.flatnonzero((e[1:] > lo_keV) & (e[:-1] < hi_keV))
        if len(k) == 0:
            raise ValueError(f"no channel overlaps {lo_keV}-{hi_keV} keV (edges {e[0]:.0f}-{e[-1]:.0f} keV)")
        return tuple(int(i) for i in k)

    @property
    def param_names(self) -> list[str]:
        return [p.name for p in self.params]

    @property
    def free_names(self) -> list[str]:
        return [p.name for p in self.params if not p.fixed]

    def param(self, name: str) -> Param:
        for p in self.params:
            if p.name == name:
                return p
        raise KeyError(f"{self!r} has no parameter {name!r}")

    def with_effect(self, name: str) -> MeasurementModel:
        return MeasurementModel(self.scenario, (*self.effects, name), self.channels)

    def with_params(self, **changes: dict[str, Any]) -> MeasurementModel:
        """A copy with some Param fields changed, e.g. ``with_params(z={"fixed": False})``."""
        m = MeasurementModel(self.scenario, self.effects, self.channels)
        m.params = [replace(p, **changes[p.name]) if p.name in changes else p for p in self.params]
        return m

    def defaults(self) -> dict[str, float]:
        return {p.name: p.value for p in self.params}

    def _theta(self, theta: Theta) -> dict[str, np.ndarray]:
        unknown = set(theta) - set(self.param_names)
        if unknown:
            raise KeyError(f"{self!r} has no parameter(s) {sorted(unknown)}")
        full = self.defaults()
        full.update(theta)
        return {k: _col(v) for k, v in full.items()}

    def _context(self, th: dict[str, np.ndarray], frames: Frames, offsets: np.ndarray | None) -> Context:
        pos = frames.positions if offsets is None else frames.positions + offsets
        for part in self._parts:
            pos = part.positions(th, pos, frames.t)
        return Context(pos=pos, yaw=frames.yaw, t=frames.t, scenario=self.scenario, walls=self._walls)

    def _sources(self, th: dict[str, np.ndarray]) -> list[tuple[np.ndarray, ...]]:
        srcs = [(th["x"], th["y"], th["z"], th["cps_at_1m"])]
        for part in self._parts:
            srcs += part.extra_sources(th)
        return srcs

    def _source_rate(self, th: dict[str, np.ndarray], ctx: Context) -> np.ndarray:
        total = 0.0
        for sx, sy, sz, s in self._sources(th):
            src = np.stack(np.broadcast_arrays(sx, sy, sz), axis=-1)  # (3,) or (P, 1, 3)
            d2 = ((ctx.pos - src) ** 2).sum(-1)
            dist = np.maximum(np.sqrt(d2), MIN_DISTANCE_M)
            term = expected_rate(d2, s)
            for part in self._parts:
                term = term * part.source_factor(th, src, ctx, dist)
            total = total + term
        return np.asarray(total)

    def _background_rate(self, th: dict[str, np.ndarray], ctx: Context) -> np.ndarray:
        b = th["background_cps"] * np.ones(len(ctx.t))
        for part in self._parts:
            b = part.background(th, b, ctx)
        return b

    def expected_counts(self, theta: Theta, frames: Frames, offsets: np.ndarray | None = None) -> np.ndarray:
        """Expected recorded total counts per frame: (N,) for scalar theta, (P, N) for (P,) arrays.

        ``offsets`` (N, 3) shifts the recorded positions (per-dwell pose offsets, see estimator.mle).
        """
        th = self._theta(theta)
        ctx = self._context(th, frames, offsets)
        n = self._source_rate(th, ctx) + self._background_rate(th, ctx)
        for part in self._parts:
            n = part.recorded_rate(th, n)
        return n * frames.duration

    def expected_counts_and_jacobian(self, theta: Theta, frames: Frames, offsets: np.ndarray | None = None
                                     ) -> tuple[np.ndarray, np.ndarray] | None:
        """:meth:`expected_counts` (N,) of one hypothesis (scalar theta) and their analytic derivative in the
        position offsets (N, 3), or None when an effect has no analytic derivative in the position (the caller
        then takes finite differences). One evaluation of the frames instead of four shifted copies."""
        if not all(part.supports_position_grad() for part in self._parts):
            return None
        th = self._theta(theta)
        if any(np.size(v) != 1 for v in th.values()):
            return None
        ctx = self._context(th, frames, offsets)
        total: Any = 0.0
        dtotal: Any = 0.0
        sources = [(np.stack(np.broadcast_arrays(sx, sy, sz), axis=-1).reshape(3), s)
                   for sx, sy, sz, s in self._sources(th)]
        if len(sources) > 1:
            for part in self._parts:
                part.prepare_grad(th, [src for src, _ in sources], ctx)
        for src, s in sources:
            diff = ctx.pos - src
            d2 = (diff**2).sum(-1)
            dist = np.maximum(np.sqrt(d2), MIN_DISTANCE_M)
            term = expected_rate(d2, s)
            # d (s / max(d2, m^2)) / d pos = -2 s (pos - src) / d2^2 where the distance is not clamped
            dterm = np.where((d2 > MIN_DISTANCE_M**2)[:, None], (-2.0 * term / np.maximum(d2, 1e-300))[:, None] * diff,
                             0.0)
            for part in self._parts:
                got = part.source_factor_grad(th, src, ctx, dist)
                if got is None:
                    return None
                f, df = got
                dterm = dterm * (np.reshape(f, (-1, 1)) if np.ndim(f) else f) + term[:, None] * df
                term = term * f
            total = total + term
            dtotal = dtotal + dterm
        b = th["background_cps"] * np.ones(len(ctx.t))
        db: Any = 0.0
        for part in self._parts:
            got = part.background_grad(th, b, db, ctx)
            if got is None:
                return None
            b, db = got
        n = total + b
        dn = np.broadcast_to(dtotal + db, (len(n), 3))
        for part in self._parts:
            got = part.recorded_rate_grad(th, n, dn)
            if got is None:
                return None
            n, dn = got
        return n * frames.duration, dn * frames.duration[:, None]
