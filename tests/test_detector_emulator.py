"""The emulator's counts: Poisson statistics, 1/d^2, dead time, walls, air, anisotropy, background, gain drift.

Statistical bounds are derived from the sample size: a mean of N Poisson draws of rate lam has
standard error sqrt(lam / N); the dispersion statistic (N - 1) s^2 / lam is chi-square with N - 1
degrees of freedom. Bounds are at 4.5 sigma (two-sided p ~ 7e-6 per check), seeds are fixed.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from detector_fw_sim import response, transport
from detector_fw_sim.emulator import DetectorEmulator
from detector_fw_sim.scene import load_scene, validate_scene
from radseek.geometry import path_lengths

Z = 4.5  # sigma of every statistical bound


def make_scene(background: float = 0.0, cps: float = 1000.0, walls: list | None = None, **effects) -> object:
    data = load_scene().model_dump()
    data["sources"] = [{"nuclide": "Cs-137", "position": [0.0, 0.0, 1.0], "cps_at_1m": cps}]
    data["background"]["cps"] = background
    data["walls"] = walls or []
    data["bounds"] = {"min": [-20, -20, 0], "max": [20, 20, 3]}
    for name, params in effects.items():
        data["effects"][name].update({"enabled": True, **params})
    return validate_scene(data, "test scene")


def pose(x: float, y: float = 0.0, z: float = 1.0, yaw: float | None = None) -> np.ndarray:
    """A pose whose axis points at the source at (0, 0, 1) unless yaw is given."""
    if yaw is None:
        yaw = math.atan2(-y, -x)
    return np.array([x, y, z, yaw])


def test_counts_are_poisson_per_channel_and_seeded():
    em = DetectorEmulator(make_scene(background=30.0), seed=11)
    n = 4000
    p = np.tile(pose(2.0), (n, 1))
    t, d = np.zeros(n), np.full(n, 0.1)
    lam = em.expected_counts(p[:1], t[:1], d[:1])[0]
    draws = em.draw_many(p, t, d)
    assert draws.dtype == np.int64 and draws.shape == (n, 32)
    for k in np.flatnonzero(lam > 0.5):
        mean = draws[:, k].mean()
        assert abs(mean - lam[k]) < Z * math.sqrt(lam[k] / n), f"channel {k}"
        disp = (n - 1) * draws[:, k].var(ddof=1) / lam[k]
        lo, hi = stats.chi2.ppf([stats.norm.cdf(-Z), stats.norm.cdf(Z)], n - 1)
        assert lo < disp < hi, f"channel {k}: variance/mean {disp / (n - 1):.3f}"
    tot = draws.sum(1)
    assert abs(tot.mean() - lam.sum()) < Z * math.sqrt(lam.sum() / n)
    # same seed, same draws; another seed, other draws
    a = DetectorEmulator(make_scene(background=30.0), seed=5).draw_many(p[:50], t[:50], d[:50])
    b = DetectorEmulator(make_scene(background=30.0), seed=5).draw_many(p[:50], t[:50], d[:50])
    c = DetectorEmulator(make_scene(background=30.0), seed=6).draw_many(p[:50], t[:50], d[:50])
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    single = DetectorEmulator(make_scene(background=30.0), seed=5).draw(p[0], 0.0, 0.1)
    assert single.shape == (32,) and single.dtype == np.int64


def test_source_term_sums_to_cps_at_1m_over_d_squared_in_3d():
    em = DetectorEmulator(make_scene(cps=1600.0), seed=0)
    # 1 m facing the source: the channel sum is exactly cps_at_1m (the dataset-spec definition)
    assert em.expected_counts(pose(1.0)[None], np.zeros(1), np.ones(1)).sum() == pytest.approx(1600.0)
    xs = np.array([1.0, 2.0, 3.0, 5.0])
    poses = np.array([pose(x) for x in xs])
    rates = em.expected_counts(poses, np.zeros(4), np.ones(4)).sum(1)
    assert rates == pytest.approx(1600.0 / xs**2)
    # 3-D distance: 3 m horizontally and 4 m up is 5 m
    up = np.array([[3.0, 0.0, 5.0, math.pi]])
    assert em.expected_counts(up, np.zeros(1), np.ones(1)).sum() == pytest.approx(1600.0 / 25.0)


def test_rate_follows_inverse_square_statistically():
    em = DetectorEmulator(make_scene(cps=2000.0), seed=3)
    xs = np.repeat([1.0, 1.5, 2.0, 3.0, 4.0], 300)
    poses = np.array([pose(x) for x in xs])
    counts = em.draw_many(poses, np.zeros(len(xs)), np.full(len(xs), 0.1)).sum(1)
    # Poisson maximum-likelihood fit of log(rate) = a + b log(d): the slope must be -2 within its error
    d_unique = np.unique(xs)
    sums = np.array([counts[xs == x].sum() for x in d_unique])
    exposure = np.array([(xs == x).sum() * 0.1 for x in d_unique])
    X = np.column_stack([np.ones_like(d_unique), np.log(d_unique)])
    beta = np.array([np.log(2000.0), -2.0]) + 0.1
    for _ in range(50):  # Newton on the Poisson log-likelihood
        mu = exposure * np.exp(X @ beta)
        beta = beta + np.linalg.solve(X.T @ (mu[:, None] * X), X.T @ (sums - mu))
    cov = np.linalg.inv(X.T @ ((exposure * np.exp(X @ beta))[:, None] * X))
    assert abs(beta[1] + 2.0) < Z * math.sqrt(cov[1, 1])


def test_dead_time_follows_the_paralyzable_formula():
    tau = 2e-5
    cps = np.array([100.0, 1e3, 1e4, 5e4, 2e5])
    # true total rate n at 1 m is cps + background; recorded is n exp(-n tau) in total and in every channel
    for c in cps:
        live = DetectorEmulator(make_scene(background=30.0, cps=c, dead_time={"tau_s": tau}))
        free = DetectorEmulator(make_scene(background=30.0, cps=c))
        rec = live.expected_counts(pose(1.0)[None], np.zeros(1), np.ones(1))[0]
        true = free.expected_counts(pose(1.0)[None], np.zeros(1), np.ones(1))[0]
        n = c + 30.0
        assert rec.sum() == pytest.approx(n * math.exp(-n * tau), rel=1e-9)
        assert rec / true == pytest.approx(np.full(32, math.exp(-n * tau)), rel=1e-9)
    # paralyzable: recorded rate peaks at n = 1/tau and falls beyond it
    em = DetectorEmulator(make_scene(cps=1.0 / tau, dead_time={"tau_s": tau}), seed=4)
    peak = em.expected_counts(pose(1.0)[None], np.zeros(1), np.ones(1)).sum()
    assert peak == pytest.approx(1.0 / tau / math.e)
    beyond = DetectorEmulator(make_scene(cps=3.0 / tau, dead_time={"tau_s": tau}))
    assert beyond.expected_counts(pose(1.0)[None], np.zeros(1), np.ones(1)).sum() < peak
    # draws agree with the formula within Poisson error
    n_frames = 500
    draws = em.draw_many(np.tile(pose(1.0), (n_frames, 1)), np.zeros(n_frames), np.full(n_frames, 0.1)).sum(1)
    lam = peak * 0.1
    assert abs(draws.mean() - lam) < Z * math.sqrt(lam / n_frames)


def test_wall_transmission_matches_the_analytic_path_length():
    wall = {"start": [1.0, -5.0], "end": [1.0, 5.0], "thickness": 0.2, "height": 3.0, "material": "concrete"}
    shielded = DetectorEmulator(make_scene(walls=[wall], wall_attenuation={}), seed=8)
    open_ = DetectorEmulator(make_scene(walls=[wall]))  # the wall is mapped but the effect is off
    ys = np.array([0.0, 0.5, 1.0, 2.0])
    poses = np.array([pose(2.0, y) for y in ys])
    ratio = (shielded.expected_counts(poses, np.zeros(4), np.ones(4)).sum(1)
             / open_.expected_counts(poses, np.zeros(4), np.ones(4)).sum(1))
    # analytic: the source (0,0,1)-detector (2,y,1) line crosses the slab x in [0.9, 1.1] over 0.2 * |p - s| / 2
    L = 0.2 * np.hypot(2.0, ys) / 2.0
    assert path_lengths(poses[:, :3], np.array([0.0, 0.0, 1.0]), shielded._walls) == pytest.approx(L)
    # each line is attenuated at its own energy: sum_l w_l exp(-mu_l L)
    src = shielded._sources[0]
    mu_l = src.wall_mu[0]
    expected = (src.weights[None, :] * np.exp(-L[:, None] * mu_l[None, :])).sum(1)
    assert ratio == pytest.approx(expected, rel=1e-9)
    # the 662 keV line dominates: the photopeak channel follows exp(-mu(662) L) with concrete's XCOM mu
    mu662 = response.mu_per_m("concrete", 661.657)
    peak = (shielded.expected_counts(poses, np.zeros(4), np.ones(4))[:, 13]
            / open_.expected_counts(poses, np.zeros(4), np.ones(4))[:, 13])
    assert peak == pytest.approx(np.exp(-mu662 * L), rel=1e-6)
    # the truth reports mu at the main line
    assert shielded.scene.truth().effects["wall_attenuation"]["mu_per_m"] == pytest.approx(mu662, rel=1e-3)
    # a detector on the source's side of the wall sees no attenuation
    same_side = np.array([pose(0.5, 0.3)])
    assert (shielded.expected_counts(same_side, np.zeros(1), np.ones(1)).sum()
            == pytest.approx(open_.expected_counts(same_side, np.zeros(1), np.ones(1)).sum()))


def test_air_attenuation_uses_the_real_coefficient():
    em = DetectorEmulator(make_scene(air_attenuation={}))
    free = DetectorEmulator(make_scene())
    poses = np.array([pose(x) for x in (1.0, 20.0, 60.0)])
    r = (em.expected_counts(poses, np.zeros(3), np.ones(3))[:, 13]
         / free.expected_counts(poses, np.zeros(3), np.ones(3))[:, 13])
    assert r == pytest.approx(np.exp(-0.0093 * np.array([1.0, 20.0, 60.0])), rel=0.01)


def test_anisotropy_versus_bearing():
    params = {"fraction": 0.5, "half_angle_deg": 30.0, "edge_deg": 4.0}
    em = DetectorEmulator(make_scene(anisotropy=params), seed=9)
    free = DetectorEmulator(make_scene())
    # detector at (2, 0, 1), source at (0, 0, 1): yaw 0 points away (source straight behind), yaw pi faces it
    yaws = np.radians(np.arange(0, 360, 5.0))
    poses = np.column_stack([np.full_like(yaws, 2.0), np.zeros_like(yaws), np.ones_like(yaws), yaws])
    ratio = (em.expected_counts(poses, np.zeros(len(yaws)), np.ones(len(yaws))).sum(1)
             / free.expected_counts(poses, np.zeros(len(yaws)), np.ones(len(yaws))).sum(1))
    theta = np.minimum(yaws, 2 * np.pi - yaws)  # angle between back direction and the source
    expected = 1 - 0.5 * (1 - np.tanh((theta - np.radians(30)) / np.radians(4))) / 2
    assert ratio == pytest.approx(expected, rel=1e-9)
    assert ratio[0] == pytest.approx(0.5, abs=1e-3) and ratio[36] == pytest.approx(1.0)
    # draws: facing vs back-to-source count ratio is 0.5 within Poisson error
    n = 600
    back = em.draw_many(np.tile([2.0, 0, 1, 0.0], (n, 1)), np.zeros(n), np.full(n, 0.1)).sum()
    front = em.draw_many(np.tile([2.0, 0, 1, np.pi], (n, 1)), np.zeros(n), np.full(n, 0.1)).sum()
    r = back / front
    sigma = r * math.sqrt(1 / back + 1 / front)
    assert abs(r - float(expected[0])) < Z * sigma
    assert transport.back_angle(np.array([[2.0, 0, 1]]), np.array([0.0]), np.array([0, 0, 1.0]))[0] == 0.0


def test_background_gradient_and_second_source():
    em = DetectorEmulator(make_scene(background=30.0, cps=1e-9, background_gradient={"gx": 2.0, "gy": -1.0}))
    pts = np.array([[0.0, 0.0, 100.0, 0.0], [5.0, 0.0, 100.0, 0.0], [5.0, 4.0, 100.0, 0.0], [-20.0, 0.0, 100.0, 0.0]])
    bg = em.background_rates(pts, np.zeros(4)).sum(1)
    assert bg == pytest.approx([30.0, 40.0, 36.0, 0.0])  # B + gx x + gy y, never negative
    two = DetectorEmulator(make_scene(second_source={"x": 3.0, "y": 0.0, "z": 1.0, "cps_at_1m": 500.0}))
    one = DetectorEmulator(make_scene())
    p = np.array([pose(1.5)])
    got = two.expected_counts(p, np.zeros(1), np.ones(1)).sum()
    assert got == pytest.approx(one.expected_counts(p, np.zeros(1), np.ones(1)).sum() + 500.0 / 1.5**2)


def test_gain_drift_moves_the_photopeak_not_the_total():
    em = DetectorEmulator(make_scene(gain_drift={"percent_per_min": 2.0}))
    t = np.array([0.0, 300.0, 600.0])  # gain 1.0, 1.1, 1.2
    rates = em.expected_counts(np.tile(pose(1.0), (3, 1)), t, np.ones(3))
    edges = em.channel_edges_keV
    for r, g in zip(rates, (1.0, 1.1, 1.2), strict=True):
        want = int(np.searchsorted(edges, 661.657 * g, side="right") - 1)
        assert int(np.argmax(r[6:])) + 6 == want
    # over a flight (2 min at 2 %/min: gain 1.04) the total barely changes: only the 40 keV threshold moves.
    # (At gain 1.2 the threshold falls to 33 keV and takes in Ba K x-rays: +11 %, as a real board would.)
    total = em.expected_counts(pose(1.0)[None], np.array([120.0]), np.ones(1)).sum()
    assert total == pytest.approx(rates[0].sum(), rel=0.03)


def test_bad_frames_are_refused_with_a_clear_message():
    em = DetectorEmulator(make_scene(background=30.0), seed=0)
    with pytest.raises(ValueError, match=r"poses must be \(N, 4\)"):
        em.expected_counts(np.zeros((2, 3)), np.zeros(2), np.ones(2))
    with pytest.raises(ValueError, match="poses must be finite"):
        em.draw(np.array([np.nan, 0, 1, 0]), 0.0, 0.1)
    with pytest.raises(ValueError, match="duration must be >= 0"):
        em.draw(pose(2.0), 0.0, -0.1)
    with pytest.raises(ValueError, match="one per pose"):
        em.expected_counts(np.zeros((3, 4)), np.zeros(2), np.ones(3))
    # on top of the source the 1/d^2 law is capped (d >= 5 cm), not infinite
    assert np.isfinite(em.expected_counts(np.array([[0.0, 0.0, 1.0, 0.0]]), 0.0, 0.1)).all()


#: the benchmark's joint RC-102-001272 response: electron_escape among its effects
ESCAPE_DET = Path(__file__).resolve().parents[1] / "docs" / "img" / "rc102-001272.joint.detector.json"


def _calibrated_shares(params: dict, nuclide: str, edges: np.ndarray) -> np.ndarray:
    """Channel shares of the calibrated response (``spectra.model``, exact Gaussian per deposit point: not the
    emulator's code) with the device's electronics left out, as the emulator leaves them: unit gain, no offset,
    no pile-up, no threshold. The last channel is open above its lower edge, as the board's."""
    from spectra import model as M

    q = dict(M.baseline_params(), **{k: v for k, v in params.items() if k in M.PARAMS})
    q.update(gain=1.0, offset_keV=0.0, quadratic_per_MeV=0.0, light_yield_curvature=0.0, pileup=0.0,
             threshold_keV=0.0)
    s = M.native_shape(q, (nuclide,), np.r_[edges[:-1], response.GRID_MAX_KEV])
    return s / s.sum()


def test_emulated_spectra_follow_the_detector_files_electron_escape(tmp_path):
    """A detector file carrying the electron-escape factor f (``radseek calibrate``'s electron_escape) makes the
    emulator's Co-60 spectrum the calibrated response with the escape: seeded draws (1e6 counts) fit it by
    chi-square, and their departure from the response without the escape, projected on what the effect predicts
    (d = p_with - p_without), is 1 within its statistical error. The same file without f gives 0 on that axis."""
    from radseek_io.detector_file import read_detector_file

    raw = json.loads(ESCAPE_DET.read_text())
    f = raw["parameters"]["electron_range_factor"]
    assert 0.2 < f < 0.6
    older = dict(raw, parameters={k: v for k, v in raw["parameters"].items() if k != "electron_range_factor"})
    (tmp_path / "no-escape.json").write_text(json.dumps(older))
    params = read_detector_file(ESCAPE_DET).parameters
    edges = np.asarray(make_scene().channel_edges_keV)
    p1 = _calibrated_shares(params, "Co-60", edges)
    p0 = _calibrated_shares(dict(params, electron_range_factor=0.0), "Co-60", edges)
    d = p1 - p0
    assert 0.5 * np.abs(d).sum() > 0.02  # the effect is large enough to be seen at this sample size

    n_frames, cps = 100, 1.0e5
    for path, want in ((ESCAPE_DET, 1.0), (tmp_path / "no-escape.json", 0.0)):
        data = make_scene(cps=cps).model_dump()
        data["sources"][0]["nuclide"] = "Co-60"
        data["detector"] = str(path)
        scene = validate_scene(data, "escape scene")
        assert scene.detector.electron_range_factor == (f if want else 0.0)
        em = DetectorEmulator(scene, seed=43)
        p = np.tile(pose(1.0), (n_frames, 1))
        counts = em.draw_many(p, np.zeros(n_frames), np.full(n_frames, 0.1)).sum(0).astype(float)
        n = counts.sum()
        expect = p1 if want else p0
        keep = n * expect > 20
        chi2 = float((((counts - n * expect) ** 2) / (n * expect))[keep].sum())
        dof = int(keep.sum()) - 1
        assert chi2 < stats.chi2.ppf(stats.norm.cdf(Z), dof), f"{path.name}: chi2 {chi2:.1f} / {dof}"
        # the multinomial estimate of the amplitude along d: a = sum((x/n - p0) d / p1) / sum(d^2 / p1)
        w = d / np.maximum(p1, 1e-12)
        a = float(((counts / n - p0) * w).sum() / (d * w).sum())
        sigma = 1.0 / math.sqrt(n * float((d * w).sum()))
        assert abs(a - want) < Z * sigma + 0.01, f"{path.name}: amplitude {a:.4f} +- {sigma:.4f}, want {want}"
