"""Poisson maximum likelihood for a ``MeasurementModel``: multi-start, bounded, with pose uncertainty,
Fisher-information covariance and the Cramér-Rao bound.

Likelihood: per-frame total counts n_i ~ Poisson(mu_i(theta)). With ``pose_uncertainty=True`` the
recorded poses are uncertain (paper 003: the GPS-denied pose estimate drifts, and near a strong source
4 cm move the rate by several %): frames are grouped (:class:`PoseGroups`) and each group gets a position
offset with a Gaussian prior from the dataset's variance columns. When the reported variance grows along
the flight the error is odometry drift, one random walk in distance flown, correlated across all dwells
(so a common shift of every pose, which moves the source with it, is as uncertain as the drift itself);
otherwise the offsets are independent per dwell. The offsets are profiled out for each theta by three
Fisher-scoring steps of the penalised likelihood from zero (:func:`profile_offsets`; two chord steps with the
Jacobian at zero when mapped walls kink the likelihood; the random walk's system is banded), so the objective
is smooth in theta and its Hessian (the reported covariance) includes the pose error.

Goodness of fit: the Poisson deviance D = 2 sum [n log(n/mu) - (n - mu)] plus the offsets' penalty
sum delta^T Sigma^-1 delta. At low counts E[D] per frame is not 1 (about 1 + 1/(6 mu)), so the
p-value compares D with its exact expectation and variance under the fitted model (per-frame Poisson
moments of the deviance, minus one per free parameter), in a normal approximation.

The Cramér-Rao bound generalises paper 004 eq. 5.3-5.7 (J = sum_k H_k^T H_k / lambda_k) to any
model's free parameters: the Fisher information of Poisson counts is sum_i grad(mu_i) grad(mu_i)^T / mu_i.
"""

from __future__ import annotations

import weakref
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import Any

import numpy as np
from iminuit import Minuit
from scipy.linalg import get_lapack_funcs
from scipy.special import gammaln, ndtr, xlogy

from estimator.model import MeasurementModel
from radseek.count_model import expected_rate
from radseek.dataset import Frames
from radseek.frame_record import COUNT_DTYPE
from radseek.geometry import path_lengths

OFFSET_STEP_M = 1e-3
#: Fisher-scoring steps of the pose-offset profile (models without mapped walls; see profile_offsets)
PROFILE_STEPS = 3
#: most Fisher-scoring steps, and the fall in penalised -log L below which they stop, of the converged profile at
#: a fit's optimum (:func:`converged_profile`)
CONVERGE_STEPS = 20
CONVERGE_TOL = 1e-3
CONVERGE_HALVINGS = 6
#: MIGRAD tolerance of the multi-start search: stop at an estimated distance to the minimum of
#: 0.002 * tol * errordef = 1e-3 in -log L, far below the 0.5 of a 1-sigma step. With strategy 0 it halves
#: the model evaluations of a fit (walled lattice-wall refit 2,500 -> 1,150) for the same minima within
#: 0.3 mm on the shared datasets (iminuit's defaults: tol 0.1, strategy 1)
SEARCH_TOL = 1.0
#: a profiled multi-start fit first runs every start without the pose offsets (:func:`_screen`) and goes on
#: from the best SCREEN_KEEP minima found that lie SCREEN_APART_M apart and within SCREEN_MARGIN in -log L of
#: the best. The offsets narrow the gap between basins by about a quarter (outdoor, a first walled fit: 92 ->
#: 69 and 1483 -> 715); the margin keeps any basin the offsets could plausibly bring level. Minima closer than
#: SCREEN_APART_M are one basin to the profiled search (a wall's shadow edges separate modes by ~0.5 m)
SCREEN_KEEP = 2
SCREEN_APART_M = 0.25
SCREEN_MARGIN = 30.0
#: MIGRAD calls a screen's search may take: a start still crawling after this many is stopped where it is and
#: ranked by its value there. In every traced refit the crawlers (770-2200 calls: walled grid cells 0.29 s,
#: two-source starts 0.36 s) ended in a basin another start reached in under 500
SCREEN_NCALL = 600
#: MIGRAD calls the profiled search of a screen's runner-up basin may take (the best basin's has no such limit):
#: stopped there, it is kept only if it is already below the best basin's minimum, and then polished like any
#: best fit that stopped short. Of 151 runner-up searches traced on 40 outdoor and 40 lattice-wall flights, 18 won
#: (by 0.001-0.47 in -log L; 8 of them by under 0.01, one basin screened as two), and each was ahead of the best
#: basin after 200 calls; losers crawled on to 471 calls (outdoor seed 2, dwell 4: 0.87 s of a 1.5 s refit)
RUNNER_UP_NCALL = 200
#: the profile's pose offsets are left as they are within this many prior standard deviations, and beyond it
#: bent smoothly towards twice as many (:func:`soft_limit`)
OFFSET_LIMIT_SD = 5.0
_NO_VARIANCE = 1e-12  # m^2: axes with no reported variance get no offset
_ZERO_ROW = np.zeros((1, 3))
_PBTRF, _PBTRS = get_lapack_funcs(("pbtrf", "pbtrs"), (np.zeros(1),))
#: a minimum whose only fault is an EDM (expected distance to the minimum in -log L, with HESSE's full
#: Hessian) above MIGRAD's tolerance counts as converged below this: 0.05 is a tenth of the 0.5 that makes
#: one standard deviation, so the true minimum is within ~0.3 sigma of the *statistical* error (and far less of
#: the drift-covering covariance the localizer reports). A wall's shadow edge kinks the likelihood, so finite
#: differences there leave EDM at 0.006-0.04 however long MIGRAD goes on (lattice-wall: 10 % of searches had
#: their final fit called unconverged at such minima, 2-5 cm from the truth, and never stopped)
NEAR_MINIMUM_EDM = 0.05


# ----------------------------------------------------------------------------------- pose groups

RANDOM_WALK = "random_walk"
INDEPENDENT = "independent"
POSE_ERROR_MODELS = (RANDOM_WALK, INDEPENDENT)
#: transit frames per pose group under a random walk: ~1 m of flight at 1 m/s, so the drift a group
#: averages over (0.03 m/sqrt(m) x sqrt(1 m)) stays below the offsets it estimates
TRANSIT_CHUNK = 10
#: smallest variance increment between consecutive groups (m^2): hovering adds no drift, and a zero
#: increment would make the prior precision infinite
_MIN_INCREMENT = 1e-6


def walk_starts(frames: Frames) -> np.ndarray:
    """(N,) bool: frames that begin another odometry walk (``Frames.walk`` changes; the first frame starts one
    too). One vehicle's frames: only the first."""
    w = np.asarray(frames.walk)
    return np.r_[True, w[1:] != w[:-1]] if len(w) else np.zeros(0, dtype=bool)


def pose_error_model(frames: Frames, declared: str | None = None) -> str:
    """Which prior the recorded pose errors follow: ``declared`` (scenario.json ``pose_error``) if given,
    else ``random_walk`` when the reported variance grows along the flight (odometry drift: a random
    walk in distance flown, whose variance grows with each metre) and ``independent`` when it does not
    (an error that does not accumulate, e.g. a fix per dwell point)."""
    if declared is not None:
        if declared not in POSE_ERROR_MODELS:
            raise ValueError(f"pose_error must be one of {POSE_ERROR_MODELS}, got {declared!r}")
        return declared
    v = np.asarray(frames.var_x, dtype=float) + np.asarray(frames.var_y, dtype=float)
    if len(v) < 4 or not np.isfinite(v).all() or v.max() <= _NO_VARIANCE:
        return INDEPENDENT
    k = max(len(v) // 10, 1)
    first, last = float(np.median(v[:k])), float(np.median(v[-k:]))
    falls = (np.diff(v) < -1e-3 * v.max()) & ~walk_starts(frames)[1:]  # a random walk's variance never falls
    # (rounding aside), except where another vehicle's walk begins
    return RANDOM_WALK if last > 1.5 * max(first, _NO_VARIANCE) and falls.mean() < 0.05 else INDEPENDENT


@dataclass(frozen=True)
class PoseGroups:
    """Frames sharing one uncertain position offset, and the prior on the offsets.

    ``independent`` (per-dwell fixes): each dwell (merged across revisits) and each contiguous transit
    run has its own offset delta_g ~ N(0, diag(var_g)).
    ``random_walk`` (odometry drift, paper 003's GPS-denied flight): the pose error is one process that
    accumulates with distance flown, e(s) = sum of independent increments, so groups are consecutive runs
    (transit runs cut every ``TRANSIT_CHUNK`` frames) in time order, e_0 ~ N(0, var_0) and
    e_g - e_(g-1) ~ N(0, var_g - var_(g-1)): the reported variance's growth is the increment. Its prior
    precision is tridiagonal per axis; ``increments`` (G, 3) holds the increment variances.

    Several vehicles (paper 004's team; ``mission.team.team_frames``): each vehicle's odometry is a walk of
    its own, so the frames are concatenated vehicle by vehicle (each in time order) and a frame whose time
    is before its predecessor's starts a new walk (:func:`walk_starts`): its first group has the prior
    e ~ N(0, var) and no link to the group before it (``restarts``). One vehicle's frames are in time
    order and form one walk, as before.
    """

    index: np.ndarray  # (N,) group of each frame
    variance: np.ndarray  # (G, 3) marginal prior variance of each group's offset
    kind: str = INDEPENDENT
    increments: np.ndarray | None = None  # (G, 3) random-walk increment variances (random_walk only)
    restarts: np.ndarray | None = None  # (G,) bool: the group begins a new walk (no link to g - 1)

    @property
    def n_groups(self) -> int:
        return len(self.variance)

    @cached_property
    def active(self) -> np.ndarray:
        """(3,) axes that carry an offset (a variance was reported)."""
        return (self.variance > _NO_VARIANCE).any(axis=0)

    @staticmethod
    def from_frames(frames: Frames, kind: str | None = None) -> PoseGroups:
        kind = pose_error_model(frames, kind)
        dwell = np.asarray(frames.dwell)
        walk = walk_starts(frames)
        starts = np.r_[True, dwell[1:] != dwell[:-1]] | walk
        run = np.cumsum(starts) - 1
        if kind == RANDOM_WALK:
            first = np.flatnonzero(starts)
            within = np.arange(len(dwell)) - first[run]
            starts = starts | ((dwell < 0) & (within % TRANSIT_CHUNK == 0))
            index = np.cumsum(starts) - 1
        else:
            key = np.where(dwell >= 0, dwell, -1 - run)  # dwells merge across revisits; transit runs stay apart
            _, index = np.unique(key, return_inverse=True)
        g = int(index.max()) + 1
        var = np.zeros((g, 3))
        counts = np.bincount(index, minlength=g)
        for j, v in enumerate((frames.var_x, frames.var_y, frames.var_z)):
            var[:, j] = np.bincount(index, weights=v, minlength=g) / counts
        if kind != RANDOM_WALK:
            return PoseGroups(index=index, variance=var)
        restarts = np.zeros(g, dtype=bool)
        restarts[index[walk]] = True
        restarts[0] = True
        step = np.diff(var, axis=0, prepend=0.0)
        step[restarts] = var[restarts]  # a new walk starts from its own initial variance
        inc = np.maximum(step, _MIN_INCREMENT)
        walk_id = np.cumsum(restarts) - 1
        cum = np.cumsum(inc, axis=0)
        base = np.r_[np.zeros((1, 3)), cum][np.flatnonzero(restarts)][walk_id]  # cumsum before each walk
        return PoseGroups(index=index, variance=cum - base, kind=RANDOM_WALK, increments=inc,
                          restarts=restarts if restarts[1:].any() else None)

    # -- the prior: precision-vector products and the banded system (random walk) or 3 x 3 blocks

    def prior_times(self, delta: np.ndarray) -> np.ndarray:
        """Sigma^-1 delta for offsets (G, 3)."""
        if self.increments is None:
            return delta / np.maximum(self.variance, _NO_VARIANCE)
        w = 1.0 / self.increments  # (G, 3): precision of each step e_g - e_(g-1), with e_(-1) = 0
        prev = np.concatenate((_ZERO_ROW, delta[:-1]))
        if self.restarts is not None:
            prev[self.restarts] = 0.0  # a new walk's first step is from 0, not from the other walk
        step = (delta - prev) * w  # (G, 3)
        back = np.concatenate((step[1:], _ZERO_ROW))
        if self.restarts is not None:
            back[np.flatnonzero(self.restarts[1:])] = 0.0  # the next group is not linked to this one
        return step - back

    def penalty(self, delta: np.ndarray) -> float:
        """delta^T Sigma^-1 delta over the active axes."""
        a = self.active
        return float(np.sum(delta[:, a] * self.prior_times(delta)[:, a]))

    def solve(self, fisher: np.ndarray, rhs: np.ndarray) -> np.ndarray:
        """Solve (F + Sigma^-1) x = rhs with F (G, 3, 3) the data information of each group's offset and
        rhs (G, 3) or (G, 3, m); inactive axes get x = 0. The random-walk system is banded (bandwidth 3 in
        the stacked (group, axis) order), so this is O(G)."""
        return self.solver(fisher)(rhs)

    def solver(self, fisher: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
        """:meth:`solve` with (F + Sigma^-1) factored once, for several right-hand sides."""
        a = self.active
        g = self.n_groups
        f = fisher * (a[:, None] & a[None, :])
        if self.increments is None:
            inv = np.where(a, 1.0 / np.maximum(self.variance, _NO_VARIANCE), 1.0)
            lhs_inv = np.linalg.inv(f + inv[:, :, None] * np.eye(3))  # (G, 3, 3)

            def _solve(r: np.ndarray) -> np.ndarray:
                return lhs_inv @ (r * a[None, :, None])
        else:
            w = np.where(a, 1.0 / self.increments, 0.0)  # (G, 3)
            link = w.copy()  # precision coupling group g to g - 1 (none where a new walk starts)
            if self.restarts is not None:
                link[self.restarts] = 0.0
            diag = w + np.concatenate((link[1:], _ZERO_ROW)) + np.where(a, 0.0, 1.0)
            ab = np.zeros((4, 3 * g))
            ab[3] = (np.einsum("gjj->gj", f) + diag).ravel()
            up1 = np.zeros((g, 3))
            up1[:, 1], up1[:, 2] = f[:, 0, 1], f[:, 1, 2]  # A[3g+j-1, 3g+j]
            ab[2] = up1.ravel()
            up2 = np.zeros((g, 3))
            up2[:, 2] = f[:, 0, 2]
            ab[1] = up2.ravel()
            up3 = np.zeros((g, 3))
            up3[1:] = -link[1:]  # A[3(g-1)+j, 3g+j] couples consecutive groups of one walk
            ab[0] = up3.ravel()
            # LAPACK's banded Cholesky itself (what scipy's cholesky_banded and cho_solve_banded call, without their
            # checks: this runs a few thousand times a fit)
            chol, info = _PBTRF(ab, lower=0)
            if info != 0:
                raise np.linalg.LinAlgError(f"pose-offset system not positive definite (LAPACK pbtrf info {info})")

            def _solve(r: np.ndarray) -> np.ndarray:
                x, info = _PBTRS(chol, (r * a[None, :, None]).reshape(3 * g, -1), lower=0)
                if info != 0:
                    raise np.linalg.LinAlgError(f"pose-offset solve failed (LAPACK pbtrs info {info})")
                return x.reshape(g, 3, -1)

        def solve(rhs: np.ndarray) -> np.ndarray:
            squeeze = rhs.ndim == 2
            x = _solve(rhs[..., None] if squeeze else rhs) * a[None, :, None]
            return x[..., 0] if squeeze else x

        return solve

    def group_sum(self, values: np.ndarray) -> np.ndarray:
        """Sum (N, ...) per-frame values into (G, ...) by group: runs of consecutive frames summed in place
        (``np.add.reduceat``), O(N) where a dense (G, N) product was O(G N) (a 3,000-frame survey has ~1,000
        groups)."""
        order, starts, present = self._runs
        v = values.reshape(len(self.index), -1)
        if order is not None:
            v = v[order]
        out = np.zeros((self.n_groups, v.shape[1]))
        if len(starts):
            out[present] = np.add.reduceat(v, starts, axis=0)
        return out.reshape((self.n_groups,) + values.shape[1:])

    @cached_property
    def _runs(self) -> tuple[np.ndarray | None, np.ndarray, np.ndarray]:
        """(frame order or None when the groups are already contiguous, first row of each group, the groups)."""
        idx = np.asarray(self.index)
        order = None if np.all(np.diff(idx) >= 0) else np.argsort(idx, kind="stable")
        srt = idx if order is None else idx[order]
        present = np.unique(srt)
        return order, np.searchsorted(srt, present), present


def offset_jacobian(model: MeasurementModel, theta: dict[str, float], frames: Frames, mu0: np.ndarray,
                    central: bool = False, at: np.ndarray | None = None) -> np.ndarray:
    """d mu_i / d offset (N, 3): how each frame's expected counts move with its position offset, at the
    offsets ``at`` (N, 3; default zero; ``mu0`` the expected counts there).

    All shifted copies of the frames go through the model in one evaluation (every effect is per frame)."""
    if not central:
        return _counts_and_jacobian(model, theta, frames, at, mu0)[1]
    n = len(frames)
    shift = np.zeros((6, n, 3))
    for i in range(6):
        shift[i, :, i % 3] = (OFFSET_STEP_M, -OFFSET_STEP_M)[i // 3]
    if at is not None:
        shift += at[None]
    mu = model.expected_counts(theta, _tiled(frames, 6), offsets=shift.reshape(6 * n, 3))
    mu = mu.reshape(6, n)
    return ((mu[:3] - mu[3:]) / (2 * OFFSET_STEP_M)).T


def _counts_and_jacobian(model: MeasurementModel, theta: dict[str, float], frames: Frames, at: np.ndarray | None,
                         mu0: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The expected counts (N,) at the offsets ``at`` (N, 3; default zero) and their forward-difference
    Jacobian in the offsets (N, 3), from one model evaluation of the frames at ``at`` and at the three steps
    (every effect is per frame, so a frame's counts are the same to the last bit in either evaluation).
    ``mu0``: the counts at ``at`` already known (the Jacobian's differences take them; they are the same).

    A model whose every effect has an analytic derivative in the position
    (:meth:`MeasurementModel.expected_counts_and_jacobian`) gives the exact Jacobian from one evaluation
    instead (the unmapped walls' soft slab lengths dominated a walled fit's cost, four copies of every line of
    sight per Jacobian); the forward differences are its fallback."""
    exact = model.expected_counts_and_jacobian(theta, frames, at)
    if exact is not None:
        return exact
    n = len(frames)
    shift = np.zeros((4, n, 3))
    for i in range(3):
        shift[i + 1, :, i] = OFFSET_STEP_M
    if at is not None:
        shift += at[None]
    mu = model.expected_counts(theta, _tiled(frames, 4), offsets=shift.reshape(4 * n, 3))
    mu = mu.reshape(4, n)
    base = mu[0] if mu0 is None else mu0
    return mu[0], ((mu[1:] - base) / OFFSET_STEP_M).T


def _per_frame_set(cache: dict[tuple[int, Any], tuple[weakref.ref, Any]], frames: Frames, key: Any,
                   build: Callable[[], Any]) -> Any:
    """``build()`` for the frame set ``frames`` and ``key``, built once and kept for the last few frame sets (a fit
    asks thousands of times; every fit of a diagnose call asks for the same flight's): keyed by the frames' id,
    checked against a weak reference so that a new set at a reused address is built anew."""
    hit = cache.get((id(frames), key))
    if hit is not None and hit[0]() is frames:
        return hit[1]
    if len(cache) >= 8:
        cache.clear()
    value = build()
    cache[(id(frames), key)] = (weakref.ref(frames), value)
    return value


#: the last few frame sets tiled for the Jacobian's shifted copies: (id, k) -> (weak reference, tiled frames)
_TILED: dict[tuple[int, Any], tuple[weakref.ref, Any]] = {}


def _tiled(frames: Frames, k: int) -> Frames:
    """``k`` copies of ``frames`` one after the other (built once per frame set: a fit asks thousands of times)."""
    return _per_frame_set(_TILED, frames, k, lambda: frames.select(np.tile(np.arange(len(frames)), k)))


def profile_offsets(
    model: MeasurementModel, theta: dict[str, float], frames: Frames, groups: PoseGroups, newton_steps: int = 2
) -> tuple[np.ndarray, np.ndarray, float]:
    """Per-group offsets maximising the penalised likelihood at ``theta`` (independent or random-walk prior).

    Models without mapped walls: :data:`PROFILE_STEPS` Fisher-scoring steps from zero, the Jacobian
    re-evaluated at each iterate. ``newton_steps`` chord steps (the Jacobian taken once, at zero) for walled
    models, where the Jacobian jumps at shadow edges and scoring cycles. Near a strong source two chord steps
    are not the maximum: the truncated profile curved 40x too much along the common translation (outdoor seed 1,
    dwell 0.3 m from the source: HESSE sd 0.07 m for a 0.14-0.16 m drift); three scoring steps give the
    converged profile's optimum and sd (0.138 m) at the same cost per fit (fewer MIGRAD calls).
    This fixed number of steps keeps the objective smooth in theta for MIGRAD; the goodness of fit at the
    optimum goes on to the maximum (:func:`converged_profile`).

    Each iterate's counts come from the same model evaluation as its Jacobian (:func:`_counts_and_jacobian`:
    one evaluation with the closed-form derivative, or the frames and three shifted copies): four evaluations
    of the model a call instead of seven (three scoring steps), three instead of four (chord).

    Returns (offsets (G, 3), expected counts (N,) with offsets applied, penalty delta^T Sigma^-1 delta).
    """
    n = model.observed_counts(frames)
    if not groups.active.any():
        return np.zeros((groups.n_groups, 3)), model.expected_counts(theta, frames), 0.0
    scoring = not ("wall_attenuation" in model.effects and len(model.scenario.walls))
    steps = PROFILE_STEPS if scoring else newton_steps
    delta = np.zeros((groups.n_groups, 3))
    mu, jac = _counts_and_jacobian(model, theta, frames, None)
    solve = None
    for k in range(steps):
        # chord steps keep the Jacobian (and its factored system) from zero offsets
        delta, solve = _scoring_step(groups, n, delta, mu, jac, None if (k == 0 or scoring) else solve)
        if scoring and k < steps - 1:
            mu, jac = _counts_and_jacobian(model, theta, frames, delta[groups.index])
        else:
            mu = model.expected_counts(theta, frames, offsets=delta[groups.index])
    return delta, mu, groups.penalty(delta)


def _scoring_step(groups: PoseGroups, n: np.ndarray, delta: np.ndarray, mu: np.ndarray, jac: np.ndarray,
                  solve: Callable[[np.ndarray], np.ndarray] | None = None,
                  scale: float = 1.0) -> tuple[np.ndarray, Callable[[np.ndarray], np.ndarray]]:
    """One Fisher-scoring step (times ``scale``) of the penalised likelihood in the offsets from ``delta``, where
    the expected counts are ``mu`` and ``jac`` their Jacobian (:func:`_counts_and_jacobian`; for a chord step
    an earlier iterate's, with its factored system ``solve``). Returns (delta after the step, ``solve``);
    offsets stay within 5 prior sd."""
    active = groups.active
    if solve is None:
        jac[:, ~active] = 0.0
        mu_safe = np.maximum(mu, 1e-12)
        solve = groups.solver(groups.group_sum(jac[:, :, None] * jac[:, None, :] / mu_safe[:, None, None]))
    resid = n / np.maximum(mu, 1e-12) - 1.0
    grad = groups.group_sum(resid[:, None] * jac) - groups.prior_times(delta)
    lim = OFFSET_LIMIT_SD * np.sqrt(groups.variance)
    return np.where(active, soft_limit(delta + scale * solve(grad), lim), 0.0), solve


def soft_limit(x: np.ndarray, lim: np.ndarray) -> np.ndarray:
    """``x`` where |x| <= lim; beyond, lim + lim tanh((|x| - lim) / lim) with x's sign (continuous with its
    first derivative, never past 2 lim). A hard clip made the fixed-step profile chaotic in theta where a dwell's
    counts pushed its offset to the limit (a strong source, a model lacking two walls): the scoring steps crossed
    the clip at different iterations, the profiled -log L jumped by tens between points 0.1 mm apart in the
    source's x, and MIGRAD crawled 16,000 calls on an 8-parameter fit (uwall-1-lattice-n3-s2, 42 s)."""
    a = np.abs(x)
    with np.errstate(invalid="ignore", divide="ignore"):
        bent = np.sign(x) * (lim + lim * np.tanh((a - lim) / np.where(lim > 0, lim, 1.0)))
    return np.where(a > lim, bent, x)


def converged_profile(model: MeasurementModel, theta: dict[str, float], frames: Frames, groups: PoseGroups,
                      max_steps: int = CONVERGE_STEPS) -> tuple[np.ndarray, np.ndarray, float]:
    """:func:`profile_offsets` carried on to the maximum: damped Fisher-scoring steps (Jacobian at each
    iterate; a step that does not lower the penalised -log L is halved, up to :data:`CONVERGE_HALVINGS`
    times) until it falls by less than :data:`CONVERGE_TOL`. Every iterate kept lowers the value, so the
    result is never worse than the fixed-step profile.

    The goodness of fit and the reported nll are the profile's at its maximum: two chord steps from zero stop
    short near a strong source behind a wall (lattice-wall seed 1, 463 frames: deviance 583 against 547 at the
    maximum, p 3.5e-5 against 3.8e-3), so a fit that explains the counts was called a misfit, and every warm
    walled refit ran all its starts again (6-8 s each) to find the same minimum."""
    n = model.observed_counts(frames)
    delta, mu, penalty = profile_offsets(model, theta, frames, groups)
    if not groups.active.any():
        return delta, mu, penalty
    value = poisson_nll(n, mu) + 0.5 * penalty
    for _ in range(max_steps):
        jac = offset_jacobian(model, theta, frames, mu, at=delta[groups.index] if delta.any() else None)
        solve = None
        for halving in range(CONVERGE_HALVINGS + 1):
            # the halved steps reuse this iterate's Jacobian and factored system
            cand, solve = _scoring_step(groups, n, delta, mu, jac, solve, scale=0.5**halving)
            cand_mu = model.expected_counts(theta, frames, offsets=cand[groups.index])
            cand_pen = groups.penalty(cand)
            cand_value = poisson_nll(n, cand_mu) + 0.5 * cand_pen
            if cand_value < value:
                break
        else:
            break  # no step along the scoring direction lowers the value: at the maximum
        fall = value - cand_value
        delta, mu, penalty, value = cand, cand_mu, cand_pen, cand_value
        if fall < CONVERGE_TOL:
            break
    return delta, mu, penalty


# ----------------------------------------------------------------------------------- statistics


def poisson_nll(n: np.ndarray, mu: np.ndarray) -> float:
    """Negative log-likelihood without the constant log(n!) term."""
    mu = np.maximum(mu, 1e-12)
    return float(np.sum(mu - n * np.log(mu)))


def poisson_deviance(n: np.ndarray, mu: np.ndarray) -> np.ndarray:
    """Per-frame Poisson deviance 2 [n log(n/mu) - (n - mu)] (with 0 log 0 = 0)."""
    mu = np.maximum(mu, 1e-12)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(n > 0, n * np.log(n / mu), 0.0)
    return 2.0 * (t - (n - mu))


def deviance_moments(mu: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean and variance of one frame's Poisson deviance when counts ~ Poisson(mu).

    Exact summation over the Poisson pmf for mu < 30; the asymptotic expansion (mean 1 + 1/(6 mu)
    + 1/(6 mu^2), variance 2 + 16/(3 mu)... truncated to 2 + 2/mu) above, where it is accurate to < 1e-3.
    """
    mu = np.asarray(mu, dtype=float)
    mean = 1.0 + 1.0 / (6 * np.maximum(mu, 1e-9)) + 1.0 / (6 * np.maximum(mu, 1e-9) ** 2)
    var = 2.0 + 2.0 / np.maximum(mu, 1e-9)
    small = mu < 30
    if small.any():
        m = mu[small][:, None]
        k = np.arange(0, 90)[None, :]
        with np.errstate(invalid="ignore"):  # scipy.stats.poisson.pmf's formula and its nan for a mean < 0 or nan
            pmf = np.where(m >= 0, np.exp(xlogy(k, m) - gammaln(k + 1) - m), np.nan)
        d = poisson_deviance(np.broadcast_to(k, pmf.shape).astype(float), np.broadcast_to(m, pmf.shape))
        e = (pmf * d).sum(1)
        mean[small] = e
        var[small] = (pmf * d**2).sum(1) - e**2
    return mean, var


# ----------------------------------------------------------------------------------- starts


def pooled(frames: Frames, size: int = 10, dwells_only: bool = False) -> Frames:
    """Consecutive frames of the same dwell index pooled ``size`` at a time (counts and durations
    summed, poses and variances averaged). For the start-point search everything is pooled; with
    ``dwells_only`` transit frames stay single, so a model whose rate depends on the pose only (no
    yaw or time effects) loses nothing but the within-dwell pose jitter: a cheap in-flight refit."""
    if dwells_only:
        moving = frames.dwell < 0
        if moving.all():
            return frames
        keyed = np.where(moving, np.arange(len(frames)) * size, 0)  # each transit frame its own chunk
        return _pool(frames, size, keyed)
    return _pool(frames, size, np.zeros(len(frames), dtype=int))


def _pool(frames: Frames, size: int, salt: np.ndarray) -> Frames:
    run = np.cumsum(np.r_[True, (frames.dwell[1:] != frames.dwell[:-1]) | (salt[1:] != salt[:-1])])
    within = np.arange(len(frames)) - np.r_[0, np.flatnonzero(np.diff(run)) + 1].repeat(np.diff(
        np.r_[0, np.flatnonzero(np.diff(run)) + 1, len(frames)]))
    key = np.cumsum(np.r_[True, (run[1:] != run[:-1]) | (within[1:] // size != within[:-1] // size)]) - 1
    return block_frames(frames, key)


#: a hover block: at most this many consecutive frames of one dwell (1 s at 10 Hz)
HOVER_FRAMES = 10
#: ... whose recorded positions stay within this of the block's first (m) ...
HOVER_RADIUS_M = 0.05
#: ... and, for a model whose rate depends on the heading (anisotropy), whose headings stay within this of its
#: first (deg: a spin dwell turns 45 deg/s)
HOVER_TURN_DEG = 5.0


def hover_blocks(frames: Frames, size: int = HOVER_FRAMES, radius_m: float = HOVER_RADIUS_M,
                 turn_deg: float = HOVER_TURN_DEG) -> np.ndarray:
    """(N,) block index of each frame: consecutive frames of one dwell (``dwell >= 0``), one vehicle and one walk,
    at most ``size`` of them, whose recorded positions stay within ``radius_m`` and headings within ``turn_deg`` of
    the block's first frame; every other frame (transit, a turn) is a block of its own.

    Within a block every effect's rate is the same to second order in the pose spread (a 5 cm spread at 1 m from
    the source: 0.25 % of the rate, against 1/sqrt(n) of the block's counts), so the block's summed counts carry the
    frames' information about theta: sum_i [mu_i - n_i log mu_i] over a block of equal mu_i = mu_B d_i / D_B is
    mu_B - N_B log mu_B plus a constant (the multinomial split by live time)."""
    n = len(frames)
    if n == 0:
        return np.zeros(0, dtype=int)
    dwell, pos = np.asarray(frames.dwell), frames.positions
    yaw = np.asarray(frames.yaw, dtype=float)
    same = (dwell[1:] >= 0) & (dwell[1:] == dwell[:-1]) & (frames.vehicle[1:] == frames.vehicle[:-1]) & (
        frames.walk[1:] == frames.walk[:-1])
    block = np.empty(n, dtype=int)
    b, first = 0, 0
    block[0] = 0
    limit = np.radians(turn_deg)
    for i in range(1, n):  # one pass; the test against the block's first frame is sequential by nature
        if (same[i - 1] and i - first < size and np.hypot(*(pos[i, :2] - pos[first, :2])) <= radius_m
                and abs(pos[i, 2] - pos[first, 2]) <= radius_m
                and abs(np.angle(np.exp(1j * (yaw[i] - yaw[first])))) <= limit):
            block[i] = b
            continue
        b, first = b + 1, i
        block[i] = b
    return block


_HOVER: dict[tuple[int, Any], tuple[weakref.ref, Any]] = {}


def _hover(frames: Frames, turn_deg: float) -> tuple[np.ndarray, Frames]:
    """(first frame of each hover block, the blocks as frames) of ``frames``, built once per frame set and turn
    limit: every fit of a diagnose call searches the same flight's blocks (and keeps the model's caches keyed by
    them)."""
    def build() -> tuple[np.ndarray, Frames]:
        block = hover_blocks(frames, turn_deg=turn_deg)
        return np.flatnonzero(np.r_[True, block[1:] != block[:-1]]), block_frames(frames, block)

    return _per_frame_set(_HOVER, frames, turn_deg, build)


def block_frames(frames: Frames, block: np.ndarray) -> Frames:
    """The frames of each block (:func:`hover_blocks`) as one: counts and durations summed, position, pose
    variances and time averaged, heading the circular mean, the first frame's dwell, vehicle, walk, seq and flags."""
    starts = np.flatnonzero(np.r_[True, block[1:] != block[:-1]])
    size = np.diff(np.r_[starts, len(block)])

    def mean(v: np.ndarray) -> np.ndarray:
        return np.add.reduceat(np.asarray(v, dtype=float), starts) / size

    yaw = np.asarray(frames.yaw, dtype=float)
    return Frames(
        t=mean(frames.t), duration=np.add.reduceat(np.asarray(frames.duration, dtype=float), starts),
        x=mean(frames.x), y=mean(frames.y), z=mean(frames.z),
        yaw=np.arctan2(np.add.reduceat(np.sin(yaw), starts), np.add.reduceat(np.cos(yaw), starts)),
        var_x=mean(frames.var_x), var_y=mean(frames.var_y), var_z=mean(frames.var_z), dwell=frames.dwell[starts],
        counts=np.add.reduceat(frames.counts, starts, axis=0).astype(COUNT_DTYPE, copy=False),
        vehicle=frames.vehicle[starts], walk=frames.walk[starts], seq=frames.seq[starts], flags=frames.flags[starts],
    )


#: wall attenuation coefficients (1/m) the start grid of a walled model tries per cell: brick-like rubble
#: to concrete (Cs-137: cinder block ~3, concrete ~17 per m), so a start sits in its shadow's mode
GRID_WALL_MU = (1.0, 3.0, 10.0, 30.0)


def grid_cell_fit(u: np.ndarray, n: np.ndarray, tdur: np.ndarray, b0: float) -> tuple[np.ndarray, ...]:
    """Per cell (rows of ``u``, counts per unit cps_at_1m), the Poisson-optimal source strength and
    background (Newton on the 2-parameter likelihood, kept positive) and the -log L there."""
    s = np.full(len(u), 100.0)
    b = np.full(len(u), b0)
    for _ in range(25):
        mu = s[:, None] * u + b[:, None] * tdur
        r = n / mu - 1.0
        g1, g2 = (r * u).sum(1), (r * tdur).sum(1)
        w = n / mu**2
        h11, h12, h22 = (w * u * u).sum(1), (w * u * tdur).sum(1), (w * tdur * tdur).sum(1)
        det = h11 * h22 - h12**2
        ds = (h22 * g1 - h12 * g2) / det
        db = (h11 * g2 - h12 * g1) / det
        s = np.clip(s + ds, 1e-3, 1e7)
        b = np.clip(b + db, 1e-3, 1e5)
    mu = s[:, None] * u + b[:, None] * tdur
    return s, b, (mu - n * np.log(mu)).sum(1)


def _grid(model: MeasurementModel, frames: Frames, n_grid: int, mus: tuple[float, ...]) -> tuple[np.ndarray, ...]:
    """Cell centres ``xx``, ``yy`` of an ``n_grid`` x ``n_grid`` grid over the bounds and, for each wall mu in
    ``mus`` (1/m, through the mapped walls; 0: no walls) and each cell, the Poisson-optimal cps_at_1m and
    background of the baseline model (vectorised IRLS) on pooled ``frames`` and the -log L there, as
    (len(mus), cells) arrays."""
    frames = pooled(frames)
    sc = model.scenario
    gx = np.linspace(sc.bounds_min[0], sc.bounds_max[0], n_grid)
    gy = np.linspace(sc.bounds_min[1], sc.bounds_max[1], n_grid)
    xx, yy = (a.ravel() for a in np.meshgrid(gx, gy))
    z = model.param("z").value
    n = model.observed_counts(frames).astype(float)
    tdur = frames.duration
    cells = np.stack([xx, yy, np.full_like(xx, z)], 1)
    d2 = ((frames.positions[None, :, :] - cells[:, None, :]) ** 2).sum(-1)
    u = tdur * expected_rate(d2, 1.0)  # (P, N) counts per unit cps_at_1m
    b0 = max(sc.background_cps, 1.0)
    lengths = path_lengths(frames.positions[None, :, :], cells[:, None, :], sc.walls) if any(mus) else 0.0
    fits = [grid_cell_fit(u * np.exp(-m * lengths) if m else u, n, tdur, b0) for m in mus]
    return (xx, yy, *(np.stack([f[i] for f in fits]) for i in range(3)))


def grid_starts(model: MeasurementModel, frames: Frames, n_grid: int = 25, n_best: int = 4) -> list[dict[str, float]]:
    """Starting points for the source from a grid over the bounds (:func:`_grid`), best cells first, kept
    apart. A walled model's likelihood has a narrow mode per shadow, so its cells are ranked through the mapped
    walls at the best of :data:`GRID_WALL_MU`, which the start then carries."""
    walled = "wall_attenuation" in model.effects and bool(model.scenario.walls)
    xx, yy, s, b, nll = _grid(model, frames, n_grid, GRID_WALL_MU if walled else (0.0,))
    k = np.argmin(nll, axis=0)  # each cell at its best mu
    s, b, nll = (np.choose(k, a) for a in (s, b, nll))
    cell = max(np.ptp(xx), np.ptp(yy)) / (n_grid - 1)
    starts: list[dict[str, float]] = []
    for i in np.argsort(nll):
        if all(np.hypot(xx[i] - st["x"], yy[i] - st["y"]) > 3 * cell for st in starts):
            st = {"x": xx[i], "y": yy[i], "cps_at_1m": s[i], "background_cps": b[i]}
            if walled:
                st["wall_attenuation.mu_per_m"] = GRID_WALL_MU[k[i]]
            starts.append(st)
        if len(starts) >= n_best:
            break
    return starts


def wall_grid_ratio(model: MeasurementModel, frames: Frames, n_grid: int = 25) -> float:
    """2 delta log L of the walled model (``model``, with ``wall_attenuation``) against the wall-free one, each
    at its best cell of the start grid (:func:`_grid`, one pass; the walled one at the best of mu = 0 and
    :data:`GRID_WALL_MU`): a few vectorised Newton steps, no search. Coarse (cells 0.4-1 m apart), so a gate,
    not a test."""
    nll = _grid(model, frames, n_grid, (0.0, *GRID_WALL_MU))[4]
    return 2.0 * float(nll[0].min() - nll.min())


def second_source_starts(
    model: MeasurementModel, frames: Frames, base: dict[str, float], n_grid: int = 25, n_best: int = 3
) -> list[dict[str, float]]:
    """Starting points for ``second_source``: with the primary at ``base``, the grid cell, strength and background
    that best explain the counts (2-D Newton per cell in strength and background, pooled frames).

    The background is profiled, not held at ``base``'s: a one-source fit takes a weaker second source's flux as
    background (two-source seeds 32, 132, 173: 52-61 cps fitted against 30), and with that background held every
    cell's best strength explained nothing more (likelihood ratio 0.2-1.4), so the second source was not found."""
    frames = pooled(frames)
    sc = model.scenario
    gx = np.linspace(sc.bounds_min[0], sc.bounds_max[0], n_grid)
    gy = np.linspace(sc.bounds_min[1], sc.bounds_max[1], n_grid)
    xx, yy = (a.ravel() for a in np.meshgrid(gx, gy))
    theta = {**model.defaults(), **base, "second_source.cps_at_1m": 0.0}
    b0 = float(theta["background_cps"])
    profile_b = not model.param("background_cps").fixed
    # the rate is linear in the background: its part per cps by difference (exact for the model's b * t term)
    mu_src = model.expected_counts({**theta, "background_cps": 0.0}, frames)
    ub = model.expected_counts({**theta, "background_cps": 1.0}, frames) - mu_src
    z = model.param("second_source.z").value
    d2 = ((frames.positions[None, :, :] - np.stack([xx, yy, np.full_like(xx, z)], 1)[:, None, :]) ** 2).sum(-1)
    u = frames.duration * expected_rate(d2, 1.0)
    n = model.observed_counts(frames).astype(float)
    s2 = np.full(len(xx), 10.0)
    b = np.full(len(xx), b0)
    for _ in range(25):
        mu = np.maximum(mu_src + b[:, None] * ub + s2[:, None] * u, 1e-12)
        r, w = n / mu - 1.0, n / mu**2
        gs, hss = (r * u).sum(1), (w * u * u).sum(1)
        if profile_b:
            gb, hbb, hsb = (r * ub).sum(1), (w * ub * ub).sum(1), (w * u * ub).sum(1)
            det = np.maximum(hss * hbb - hsb**2, 1e-12 * np.maximum(hss * hbb, 1e-300))
            ds, db = (hbb * gs - hsb * gb) / det, (hss * gb - hsb * gs) / det
            b = np.clip(b + db, 0.0, None)
        else:
            ds = gs / np.maximum(hss, 1e-12)
        s2 = np.clip(s2 + ds, 0.0, 1e7)
    mu = np.maximum(mu_src + b[:, None] * ub + s2[:, None] * u, 1e-12)
    nll = (mu - n * np.log(mu)).sum(1)
    cell = max(gx[1] - gx[0], gy[1] - gy[0])
    starts: list[dict[str, float]] = []
    for i in np.argsort(nll):
        if np.hypot(xx[i] - base.get("x", np.inf), yy[i] - base.get("y", np.inf)) < 2 * cell:
            continue
        if all(np.hypot(xx[i] - st["second_source.x"], yy[i] - st["second_source.y"]) > 3 * cell for st in starts):
            st = {"second_source.x": xx[i], "second_source.y": yy[i], "second_source.cps_at_1m": s2[i]}
            if profile_b:
                st["background_cps"] = float(b[i])
            starts.append(st)
        if len(starts) >= n_best:
            break
    return starts


# ----------------------------------------------------------------------------------- fitting


class DevianceTest:
    """The goodness of fit of a deviance against its exact moments (``deviance``, ``dof``, ``deviance_expected``,
    ``deviance_sd`` fields of the dataclass using it)."""

    @property
    def deviance_per_dof(self) -> float:
        return self.deviance / max(self.dof, 1)

    @property
    def p_value(self) -> float:
        """P(D >= observed) under the fitted model, from the exact deviance moments (normal approx.)."""
        return float(ndtr(-(self.deviance - self.deviance_expected) / max(self.deviance_sd, 1e-9)))  # normal sf


@dataclass
class FitResult(DevianceTest):
    model: MeasurementModel
    values: dict[str, float]
    errors: dict[str, float]
    free_names: list[str]
    covariance: np.ndarray
    nll: float
    deviance: float
    dof: int
    expected: np.ndarray
    pose_offsets: np.ndarray
    deviance_expected: float
    deviance_sd: float
    converged: bool
    n_frames: int
    starts_tried: int = 0
    all_nll: list[float] = field(default_factory=list)
    pose_error: str = ""  # the pose-error prior used: random_walk, independent, or "" (poses taken as exact)

    @property
    def aic(self) -> float:
        return 2 * self.nll + 2 * len(self.free_names)

    @property
    def n_params(self) -> int:
        return len(self.free_names)

    def source(self) -> dict[str, float]:
        return {k: self.values[k] for k in ("x", "y", "z", "cps_at_1m")}

    def sources(self) -> list[dict[str, float]]:
        out = [self.source()]
        if "second_source" in self.model.effects:
            out.append({k: self.values[f"second_source.{k}"] for k in ("x", "y", "z", "cps_at_1m")})
        return out


def declared_pose_error(model: MeasurementModel) -> str | None:
    """The pose-error model a dataset declares (scenario.json ``pose_error``), or None to infer it."""
    declared = model.scenario.extra.get("pose_error")
    return declared if isinstance(declared, str) else None


class _Likelihood:
    """Half the Poisson deviance of ``names`` (the other parameters held at ``fixed``), pose offsets profiled at each
    theta when ``groups`` is given (:func:`profile_offsets`). MIGRAD takes its own finite differences (an analytic
    gradient was tried and removed: it made multi-slab diagnose calls three times dearer)."""

    def __init__(self, model: MeasurementModel, frames: Frames, names: list[str], fixed: dict[str, float],
                 groups: PoseGroups | None):
        self.model, self.frames, self.names, self.fixed, self.groups = model, frames, names, fixed, groups
        self.n = model.observed_counts(frames)

    def __call__(self, *values: float) -> float:
        theta = {**self.fixed, **dict(zip(self.names, values, strict=True))}
        if self.groups is None:
            mu, penalty = self.model.expected_counts(theta, self.frames), 0.0
        else:
            _, mu, penalty = profile_offsets(self.model, theta, self.frames, self.groups)
        return 0.5 * float(poisson_deviance(self.n, mu).sum() + penalty)


def _objective(model: MeasurementModel, frames: Frames, names: list[str], fixed: dict[str, float],
               groups: PoseGroups | None) -> _Likelihood:
    """The likelihood MIGRAD minimises (:class:`_Likelihood`)."""
    return _Likelihood(model, frames, names, fixed, groups)


def _search(fcn: Callable[..., float], model: MeasurementModel, names: list[str], start: dict[str, float],
            ncall: int = 4000) -> Minuit:
    """MIGRAD from ``start`` with the search's cheap settings (strategy 0, :data:`SEARCH_TOL`), at most ``ncall``
    calls."""
    values = [float(np.clip(start[nm], model.param(nm).lower, model.param(nm).upper)) for nm in names]
    m = Minuit(fcn, *values, name=names)
    m.errordef = Minuit.LIKELIHOOD
    m.errors = [model.param(nm).scale for nm in names]
    m.limits = [(model.param(nm).lower, model.param(nm).upper) for nm in names]
    m.strategy = 0  # cheap steps from each start: on these datasets the same minima (0.3 mm) at half the calls
    m.tol = SEARCH_TOL
    m.migrad(ncall=ncall)
    return m


def _screen(model: MeasurementModel, frames: Frames, names: list[str], fixed: dict[str, float],
            starts: list[dict[str, float]], keep: int = SCREEN_KEEP, warm: bool = False) -> list[dict[str, float]]:
    """The minima of the likelihood without pose offsets reached from ``starts``: the best ``keep`` of them
    (apart by :data:`SCREEN_APART_M`, within :data:`SCREEN_MARGIN` of the best), best first, to start the
    profiled search. ``warm``: the first start is a refit's last optimum; when its basin is the best one it
    alone goes on (it was the profiled optimum a dwell ago; a runner-up basin is kept for the profiled search
    because the offsets can reorder basins, which a first fit has no evidence against).

    Each call of the profiled likelihood costs PROFILE_STEPS Jacobians (about 8 model evaluations); without the
    offsets a call is one. Far starts crawl (a grid cell 1030 MIGRAD calls, the warm start 69, to the same
    minimum), so they crawl here, and the profiled search starts in the best basins."""
    plain = _objective(model, frames, names, fixed, None)
    minima = [(m.fval, dict(zip(names, (float(v) for v in m.values), strict=True)))
              for m in (_search(plain, model, names, st, SCREEN_NCALL) for st in starts)]
    found = sorted(minima, key=lambda r: r[0])
    if warm and _distance(found[0][1], minima[0][1]) <= SCREEN_APART_M:
        keep = 1
    kept: list[dict[str, float]] = []
    for fval, vals in found:
        if fval > found[0][0] + SCREEN_MARGIN:
            break
        if all(_distance(vals, k) > SCREEN_APART_M for k in kept):
            kept.append({**starts[0], **vals})
        if len(kept) == keep:
            break
    return kept


def _distance(a: dict[str, float], b: dict[str, float]) -> float:
    """How far apart two minima are (m): the larger of the sources' moves, the second source's too when both have
    one (two basins with the primary in one place and the second source in two are two basins)."""
    d = float(np.hypot(a["x"] - b["x"], a["y"] - b["y"]))
    if "second_source.x" in a and "second_source.x" in b:
        d = max(d, float(np.hypot(a["second_source.x"] - b["second_source.x"],
                                  a["second_source.y"] - b["second_source.y"])))
    return d


def _polish(m: Minuit) -> None:
    """Go on from ``m``'s minimum with full-strategy MIGRAD and iminuit's default tolerance."""
    m.strategy = 1
    m.tol = 0.1
    m.migrad(ncall=4000)


def _converged(m: Minuit) -> bool:
    """MIGRAD's minimum is valid, or its only faults are an EDM above tolerance or a call limit reached, with the
    EDM below :data:`NEAR_MINIMUM_EDM` (HESSE did not fail)."""
    f = m.fmin
    if f is None:
        return False
    if f.is_valid:
        return True
    return bool((f.is_above_max_edm or f.has_reached_call_limit) and not f.hesse_failed and f.edm < NEAR_MINIMUM_EDM)


def fit(
    model: MeasurementModel,
    frames: Frames,
    *,
    n_starts: int = 8,
    seed: int = 0,
    pose_uncertainty: bool = True,
    init: dict[str, float] | None = None,
    more_inits: Sequence[dict[str, float]] = (),
    warm_start: bool = False,
    hover: bool = False,
    second_grid: bool = False,
) -> FitResult:
    """Multi-start bounded Poisson MLE (MIGRAD + HESSE, errordef 0.5).

    Starts: ``init`` (if given) first, then ``more_inits`` (other given starts, e.g. an unmapped wall's runner-up
    placements: screened without pose offsets with the rest, so only the best basins are searched in full), then
    grid starts for the source (and for a second source),
    then random perturbations of the best start, up to ``n_starts`` in all. With pose offsets every start is
    first run without them (:func:`_screen`), and the profiled search goes on from the best basins found
    (``warm_start``: ``init`` is a refit's last optimum, searched alone when its basin is the best).

    ``hover``: the starts, the search and HESSE run on the flight's hover blocks (:func:`hover_blocks`: a dwell's
    frames summed a second at a time), whose likelihood is the frames' up to a constant where the rate is the
    same across a block; the optimum's pose offsets, expected counts, -log L and deviance are the frames' own.
    A 4,000-frame flight of long dwells is searched on ~500 blocks.

    ``second_grid``: ``init`` places the second source, and the second source's best grid start
    (:func:`second_source_starts`) is the next start: screened with ``init``, so only the better basin is searched
    in full (two separate fits of a three-slab flight's candidate each searched in full, one crawled 37 s to a
    minimum 46 worse than the other's).
    """
    rng = np.random.default_rng(seed)
    names = model.free_names
    fixed = {p.name: p.value for p in model.params if p.fixed}
    frame_groups = PoseGroups.from_frames(frames, declared_pose_error(model)) if pose_uncertainty else None
    if frame_groups is not None and not frame_groups.active.any():
        frame_groups = None
    all_frames, groups = frames, frame_groups
    if hover:
        first, blocks = _hover(frames, HOVER_TURN_DEG if model.uses_heading else 180.0)
        hover = len(first) < len(frames)
    if hover:
        frames = blocks
        if frame_groups is not None:
            groups = replace(frame_groups, index=frame_groups.index[first])
    defaults = model.defaults()
    base_starts: list[dict[str, float]] = []
    if init:
        base_starts.append({**defaults, **{k: v for k, v in init.items() if k in defaults}})
    base_starts += [{**defaults, **{k: v for k, v in st.items() if k in defaults}} for st in more_inits]
    base_starts += [{**defaults, **g} for g in grid_starts(model, frames)]
    if "second_source" in model.effects and not (init and "second_source.x" in init):
        ref = base_starts[0]
        base_starts = [{**ref, **s2} for s2 in second_source_starts(model, frames, ref)] + base_starts
    elif second_grid and "second_source" in model.effects and base_starts:
        ref = base_starts[0]
        base_starts = [ref, *({**ref, **s2} for s2 in second_source_starts(model, frames, ref, n_best=1)),
                       *base_starts[1:]]
    starts = base_starts[: max(n_starts, 1)]
    while len(starts) < n_starts:
        st = dict(starts[0])
        for name in names:
            p = model.param(name)
            st[name] = float(np.clip(st[name] + rng.normal(0, 2 * p.scale), p.lower, p.upper))
        starts.append(st)

    fcn = _objective(model, frames, names, fixed, groups)
    # MIGRAD minimises half the deviance (small terms, summed without cancellation); -log L is that plus
    # the saturated model's -log L
    n = model.observed_counts(frames)
    saturated = poisson_nll(n, n)
    if groups is not None:
        starts = _screen(model, frames, names, fixed, starts, keep=min(SCREEN_KEEP, len(starts)),
                         warm=warm_start and bool(init))
    best: Minuit | None = None
    all_nll = []
    for i, st in enumerate(starts):
        m = _search(fcn, model, names, st, RUNNER_UP_NCALL if (i and groups is not None) else 4000)
        all_nll.append(float(m.fval) + saturated)
        if best is None or m.fval < best.fval:
            best = m
    assert best is not None
    # a minimum within NEAR_MINIMUM_EDM is not searched on: there a wall's shadow edge kinks the likelihood and
    # more calls move -log L by hundredths (a three-slab drop fit: two polishes, 5,500 calls and 22 s, 0.2 lower)
    if not best.valid and best.fmin.has_reached_call_limit and best.fmin.edm >= NEAR_MINIMUM_EDM:
        # a runner-up basin's search stopped at its call limit below the best basin's minimum: go on with the
        # search's cheap settings first (polished from there at once, a two-slab fit crawled 7,710 calls)
        best.migrad(ncall=4000)
    if not best.valid and best.fmin.edm >= NEAR_MINIMUM_EDM:
        # the cheap search stopped short (call limit, EDM above tolerance; a wall's shadow edge makes the
        # likelihood kinked): polish the best minimum before calling it failed
        _polish(best)
    best.hesse()  # the full Hessian at the best minimum (MIGRAD's strategy 0 only estimates it)
    if not best.valid and best.fmin.is_above_max_edm and best.fmin.edm >= NEAR_MINIMUM_EDM:
        # with the full Hessian the distance to the minimum (EDM) is far above tolerance: strategy 0's estimated
        # Hessian had stopped MIGRAD short; go on from there rather than calling the fit unconverged
        _polish(best)
        best.hesse()
    values = {**fixed, **dict(zip(names, (float(v) for v in best.values), strict=True))}
    cov = np.array(best.covariance) if best.covariance is not None else np.full((len(names),) * 2, np.nan)
    nll = float(best.fval) + saturated
    frames, groups = all_frames, frame_groups  # the optimum's goodness of fit on the frames themselves
    n = model.observed_counts(frames)
    if groups is not None:
        pose_offsets, mu, penalty = converged_profile(model, values, frames, groups)
        nll = poisson_nll(n, mu) + 0.5 * penalty if hover else min(nll, poisson_nll(n, mu) + 0.5 * penalty)
    else:
        mu, penalty, pose_offsets = model.expected_counts(values, frames), 0.0, np.zeros((0, 3))
        nll = poisson_nll(n, mu) if hover else nll
    dev = float(poisson_deviance(n, mu).sum() + penalty)
    mean, var = deviance_moments(mu)
    return FitResult(
        model=model,
        values=values,
        errors={nm: float(e) for nm, e in zip(names, best.errors, strict=True)},
        free_names=list(names),
        covariance=cov,
        nll=nll,
        deviance=dev,
        dof=len(frames) - len(names),
        expected=mu,
        pose_offsets=pose_offsets,
        deviance_expected=float(mean.sum() - len(names)),
        deviance_sd=float(np.sqrt(var.sum())),
        converged=_converged(best),
        n_frames=len(frames),
        starts_tried=len(starts),
        all_nll=all_nll,
        pose_error=groups.kind if groups is not None else "",
    )


# ----------------------------------------------------------------------------------- Fisher / CRLB


def expected_count_gradient(model: MeasurementModel, theta: dict[str, Any], frames: Frames,
                            names: list[str] | None = None) -> np.ndarray:
    """d mu_i / d theta_j by central differences: (N, k) over ``names`` (default: free parameters)."""
    names = model.free_names if names is None else names
    full = {**model.defaults(), **theta}
    grads = []
    for nm in names:
        p = model.param(nm)
        h = 1e-4 * max(abs(full[nm]), p.scale)
        lo, hi = max(full[nm] - h, p.lower), min(full[nm] + h, p.upper)
        up = model.expected_counts({**full, nm: hi}, frames)
        dn = model.expected_counts({**full, nm: lo}, frames)
        grads.append((up - dn) / (hi - lo))
    return np.stack(grads, axis=-1)


def fisher_information(model: MeasurementModel, theta: dict[str, Any], frames: Frames,
                       names: list[str] | None = None) -> np.ndarray:
    """Poisson Fisher information sum_i grad mu_i grad mu_i^T / mu_i (paper 004 eq. 5.3, generalised)."""
    g = expected_count_gradient(model, theta, frames, names)
    mu = np.maximum(model.expected_counts({**model.defaults(), **theta}, frames), 1e-12)
    return (g / mu[:, None]).T @ g


def crlb(model: MeasurementModel, theta: dict[str, Any], frames: Frames, names: list[str] | None = None) -> np.ndarray:
    """Cramér-Rao lower bound: the inverse Fisher information for the flown poses (k x k)."""
    return np.linalg.pinv(fisher_information(model, theta, frames, names))


@dataclass(frozen=True)
class FitCheck(DevianceTest):
    """Goodness of fit of a given estimate (any localizer's) under the common count model, pose offsets profiled
    as the MLE does, and the Cramér-Rao bound at the flown poses."""

    deviance: float
    dof: int
    deviance_expected: float
    deviance_sd: float
    crlb: np.ndarray  # (k, k) over ``names``
    names: list[str]


def check_estimate(model: MeasurementModel, theta: dict[str, float], frames: Frames) -> FitCheck:
    """The deviance of ``theta`` (exact per-frame moments; pose offsets profiled, their Gaussian penalty kept, as
    in :func:`fit`) and the CRLB at ``theta`` (paper 004 eq. 5.3-5.7): what a localizer that reports neither is
    held to. ``dof`` counts the model's free parameters as fitted."""
    theta = {**model.defaults(), **theta}
    n = model.observed_counts(frames)
    groups = PoseGroups.from_frames(frames, declared_pose_error(model))
    if groups.active.any():
        _, mu, penalty = converged_profile(model, theta, frames, groups)
    else:
        mu, penalty = model.expected_counts(theta, frames), 0.0
    mean, var = deviance_moments(mu)
    names = model.free_names
    return FitCheck(float(poisson_deviance(n, mu).sum() + penalty), len(frames) - len(names),
                    float(mean.sum()), float(np.sqrt(var.sum())), crlb(model, theta, frames, names), list(names))


def summary(result: FitResult) -> dict[str, Any]:
    """Plain-dict view for JSON reports."""
    return {
        "model": list(result.model.effects),
        "values": result.values,
        "errors": result.errors,
        "deviance": result.deviance,
        "dof": result.dof,
        "deviance_per_dof": result.deviance_per_dof,
        "p_value": result.p_value,
        "nll": result.nll,
        "aic": result.aic,
        "converged": result.converged,
    }
