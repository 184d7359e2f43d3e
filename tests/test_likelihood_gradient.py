"""The profiled likelihood's gradient for MIGRAD (``estimator.mle._Likelihood.grad``) against numerical derivatives
of the likelihood itself, iminuit's own check of it, and fits with and without it, on flights of the independent
forward model (``benchmarks.forward2``): unmapped walls, a second source, a random-walk pose error (so the pose
offsets are profiled at every call)."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
from iminuit import Minuit

from benchmarks.forward2 import FlightSpec, random_unmapped_wall, simulate
from estimator import mle
from estimator.model import MeasurementModel, UnmappedWall

WALLS = ("unmapped_wall", "unmapped_wall_2")


def _flight(seed: int, n_walls: int = 2, second: bool = True, geometry: str = "lattice"):
    spec = FlightSpec(geometry=geometry, pose_error="random_walk", scatter=0.02)
    fx = {}
    if n_walls:
        fx["unmapped_wall"] = random_unmapped_wall(spec, seed, 0.5, np.random.default_rng(seed), n_walls)
    if second:
        fx["second_source"] = {"x": 8.5, "y": 1.5, "z": 0.0, "cps_at_1m": 650.0}
    return simulate(FlightSpec(geometry=geometry, pose_error="random_walk", scatter=0.02, effects=fx), seed=seed)


def _truth(ds, model: MeasurementModel) -> dict[str, float]:
    """The flight's true parameters in the model's terms (walls as placements seen from the source)."""
    src = ds.truth.sources[0]
    th = {**model.defaults(), "x": src.x, "y": src.y, "cps_at_1m": src.cps_at_1m,
          "background_cps": ds.scenario.background_cps}
    uw = ds.truth.effects.get("unmapped_wall", {})
    for w, nm in zip(uw.get("walls", []), (e for e in WALLS if e in model.effects), strict=False):
        slab = np.array([*w["start"], *w["end"], w["thickness"], w["height"]])
        placement = UnmappedWall.placement(slab, np.array([src.x, src.y]))
        assert placement is not None
        th.update({f"{nm}.{k}": v for k, v in placement.items()})
        th[f"{nm}.mu_per_m"] = uw["mu_per_m"] * w["thickness"] / model.param(f"{nm}.thickness").value
    if "second_source" in model.effects:
        th.update({f"second_source.{k}": v for k, v in ds.truth.effects["second_source"].items() if k != "nuclide"})
    return th


def _likelihood(ds, effects):
    model = MeasurementModel(ds.scenario, effects)
    groups = mle.PoseGroups.from_frames(ds.frames, mle.declared_pose_error(model))
    assert groups.kind == mle.RANDOM_WALK and groups.active.any()
    fixed = {p.name: p.value for p in model.params if p.fixed}
    return model, mle._objective(model, ds.frames, model.free_names, fixed, groups)


def _central(lik, x: np.ndarray, j: int, h: float) -> float:
    up, dn = x.copy(), x.copy()
    up[j] += h
    dn[j] -= h
    return (lik(*up) - lik(*dn)) / (2 * h)


@pytest.fixture(scope="module")
def walled_flight():
    return _flight(seed=3)


def _points(model, lik, truth, rng, n):
    """The truth and ``n`` points around it (a few steps of each parameter's scale): where MIGRAD walks."""
    names = model.free_names
    x0 = np.array([truth[nm] for nm in names])
    scale = np.array([model.param(nm).scale for nm in names])
    return [x0] + [x0 + rng.normal(0, 0.5, len(names)) * scale for _ in range(n)]


@pytest.mark.slow
def test_the_gradient_is_the_derivative_of_the_profiled_likelihood(walled_flight, monkeypatch):
    """With the pose offsets' profile run to its maximum, the gradient (offsets held, envelope theorem) is the
    derivative of the profiled -log L. Reference: central differences of the likelihood with steps H = 1e-3 of each
    parameter's scale, Richardson-extrapolated from H and H/2; tolerance: the error of a step-H difference
    (|D(H) - D(H/2)|, 3/4 of D(H)'s O(H^2) error), plus the gradient's own step error measured the same way (its
    steps GRAD_STEP and GRAD_STEP / 2), plus rounding (1e-9 of the gradient's size)."""
    monkeypatch.setattr(mle, "PROFILE_STEPS", 30)  # the profile converged (to 1e-9): the envelope theorem holds
    ds = walled_flight
    model, lik = _likelihood(ds, (*WALLS, "second_source"))
    monkeypatch.setattr(mle, "GRAD_STEP", mle.GRAD_STEP / 2)
    _, lik_half = _likelihood(ds, (*WALLS, "second_source"))
    names = model.free_names
    for x in _points(model, lik, _truth(ds, model), np.random.default_rng(0), 2):
        g, g_half = lik.grad(*x), lik_half.grad(*x)
        for j, nm in enumerate(names):
            h = 1e-3 * model.param(nm).scale
            d1, d2 = _central(lik, x, j, h), _central(lik, x, j, h / 2)
            ref = (4 * d2 - d1) / 3
            tol = abs(d1 - d2) + abs(g[j] - g_half[j]) + 1e-9 * np.abs(g).max()
            assert abs(g[j] - ref) <= tol, (nm, g[j], ref, d1, d2, g_half[j])


def test_with_the_fits_profile_the_gradient_is_within_a_few_percent(walled_flight):
    """With the fit's profile (a few Fisher steps, not the maximum) the offsets' own gradient is not quite zero, and
    the gradient adds its first-order effect (the offsets' implicit derivative in theta, -H^-1 H_delta,theta). Away
    from a minimum, measured in each parameter's scale (g_j x scale_j), it is within 10 % of the likelihood's
    central differences at every point MIGRAD might visit (a descent direction within 6 degrees), and closer than
    the plain envelope gradient at each: the term does what it is for. At a minimum, where a relative error means
    nothing, the fits below reach the same minimum with and without the gradient."""
    ds = walled_flight
    model, lik = _likelihood(ds, (*WALLS, "second_source"))
    names = model.free_names
    scale = np.array([model.param(nm).scale for nm in names])
    for x in _points(model, lik, _truth(ds, model), np.random.default_rng(1), 4):
        ref = np.array([_central(lik, x, j, 1e-3 * model.param(nm).scale) for j, nm in enumerate(names)])
        delta, mu, _ = lik.profile(x)
        plain = lik.count_jacobian(lik.theta(x), x, delta[lik.groups.index]) @ (1.0 - lik.n / mu)
        err = np.linalg.norm((lik.grad(*x) - ref) * scale) / np.linalg.norm(ref * scale)
        assert err < 0.1
        assert err < np.linalg.norm((plain - ref) * scale) / np.linalg.norm(ref * scale)


def test_iminuits_own_check_accepts_the_gradient(capfd):
    """MIGRAD at strategy 1 checks a user gradient against its own numerical one (MnHesse's "Analytical calculator
    ... numerical ..." line at print level 1). At the minimum both are near zero; a gradient error dg moves the
    minimum by dg / g2 (internal coordinates), against a standard deviation of 1 / sqrt(g2) (errordef 0.5):
    every parameter's disagreement is under 0.05 of its standard deviation."""
    ds = _flight(seed=5, n_walls=1, second=False)
    model, lik = _likelihood(ds, ("unmapped_wall",))
    truth = _truth(ds, model)
    names = model.free_names
    m = Minuit(lik, *[truth[nm] for nm in names], name=names, grad=lik.grad)
    m.errordef = Minuit.LIKELIHOOD
    m.errors = [model.param(nm).scale for nm in names]
    m.limits = [(model.param(nm).lower, model.param(nm).upper) for nm in names]
    m.strategy = 1
    m.print_level = 1
    m.migrad()
    m.print_level = 0
    log = capfd.readouterr()
    line = next(ln for ln in (log.out + log.err).splitlines() if "Analytical calculator" in ln)
    ana, num, g2 = (np.array(v.split(), dtype=float) for v in re.findall(r"\[([^\]]*)\]", line))
    assert m.valid and m.ngrad > 0
    assert len(ana) == len(names)
    assert np.all(np.abs(ana - num) / np.sqrt(g2) < 0.05), (ana, num, g2)


def test_a_parameter_the_model_takes_only_as_a_scalar_gets_its_own_differences(walled_flight, monkeypatch):
    """An effect that cannot evaluate some parameter as an array of hypotheses declares it (``scalar_params``), and
    the gradient differences it one evaluation at a time: the same gradient as from the arrays."""
    ds = walled_flight
    model, lik = _likelihood(ds, (*WALLS, "second_source"))
    x = np.array([_truth(ds, model)[nm] for nm in model.free_names])
    vectorised = lik.grad(*x)
    monkeypatch.setattr(UnmappedWall, "scalar_params", lambda self: tuple(
        nm for nm in UnmappedWall._placement_keys(self.name)))
    model, lik = _likelihood(ds, (*WALLS, "second_source"))
    assert {"x", "y", "unmapped_wall.r", "unmapped_wall_2.length"} <= model.scalar_params
    np.testing.assert_allclose(lik.grad(*x), vectorised, rtol=1e-9, atol=1e-9 * np.abs(vectorised).max())


def test_at_a_bound_the_difference_is_one_sided(walled_flight, monkeypatch):
    """A parameter at its bound (a second source of strength 0) is differenced inside the bounds only: its derivative
    is the one-sided difference of the likelihood (profile converged; the gradient's forward step's O(h) error is
    ~1e-6 of it), and a source that emits nothing has no gradient in its position."""
    monkeypatch.setattr(mle, "PROFILE_STEPS", 30)
    ds = walled_flight
    model, lik = _likelihood(ds, (*WALLS, "second_source"))
    names = model.free_names
    th = {**_truth(ds, model), "second_source.cps_at_1m": 0.0}
    x = np.array([th[nm] for nm in names])
    g = lik.grad(*x)
    j = names.index("second_source.cps_at_1m")
    h = 1e-3 * model.param(names[j]).scale
    up, up2 = x.copy(), x.copy()
    up[j] += h
    up2[j] += 2 * h
    one_sided = (-3 * lik(*x) + 4 * lik(*up) - lik(*up2)) / (2 * h)  # second-order forward difference
    assert g[j] == pytest.approx(one_sided, rel=1e-4)
    for k in ("x", "y"):
        assert g[names.index(f"second_source.{k}")] == 0.0


@pytest.mark.slow
@pytest.mark.parametrize("seed, n_walls, second", [(11, 0, False), (12, 1, False), (13, 2, True)])
def test_fits_with_and_without_the_gradient_reach_the_same_minimum(seed, n_walls, second, monkeypatch):
    """The whole fit (screen, profiled search, polish, HESSE) from the same starts, MIGRAD given the gradient or
    left to its own finite differences: the same minimum (-log L within 0.01, the source within 1 cm) or, where the
    surface is flat (two walls and a second source), a lower one with the gradient: seed 13 stops 0.91 lower, the
    source 1.6 cm away with a standard error of 8-10 cm. On a quadratic surface two points delta apart in -log L lie
    at most sqrt(2 delta) standard errors apart along the flattest direction: that bounds the source's move."""
    ds = _flight(seed, n_walls, second)
    effects = (*WALLS[:n_walls], *(("second_source",) if second else ()))
    model = MeasurementModel(ds.scenario, effects)
    init = _truth(ds, model) if n_walls else None  # a wall's placement starts from where the selection puts it
    fits = {}
    for use in (False, True):
        monkeypatch.setattr(mle, "USE_GRADIENT", use)
        fits[use] = mle.fit(model, ds.frames, n_starts=3, seed=seed, init=init)
    a, b = fits[False], fits[True]
    assert a.converged and b.converged
    assert b.nll <= a.nll + 0.01  # the gradient never stops higher
    moved = np.hypot(a.values["x"] - b.values["x"], a.values["y"] - b.values["y"])
    delta = a.nll - b.nll
    if delta < 0.01:
        assert moved < 0.01
    else:
        assert moved <= math.sqrt(2 * delta) * max(b.errors["x"], b.errors["y"])
