"""The composable measurement model against analytic cases, one effect at a time."""

import numpy as np
import pytest

from estimator.model import MeasurementModel
from radseek.dataset import Frames, Scenario, Wall

EDGES = np.linspace(40, 1640, 33)


def scenario(walls=()):
    return Scenario(
        channel_edges_keV=EDGES, background_cps=30.0, source_z=0.0,
        bounds_min=np.array([0.0, 0.0, 0.0]), bounds_max=np.array([10.0, 10.0, 3.0]), walls=tuple(walls),
    )


def frames(points, yaw=None, t=None, duration=0.1):
    points = np.asarray(points, dtype=float)
    n = len(points)
    rows = np.zeros((n, 42))
    rows[:, 0] = np.arange(1, n + 1) * duration if t is None else t
    rows[:, 1] = duration
    rows[:, 2:5] = points
    rows[:, 5] = 0.0 if yaw is None else yaw
    rows[:, 9] = np.arange(n)
    return Frames.from_rows(rows)


SRC = {"x": 5.0, "y": 5.0, "cps_at_1m": 1000.0, "background_cps": 30.0}


def test_baseline_is_inverse_square_plus_background():
    f = frames([[5, 5, 1], [5, 5, 2], [8, 9, 0]])
    mu = MeasurementModel(scenario()).expected_counts(SRC, f)
    d2 = np.array([1.0, 4.0, 25.0])
    assert np.allclose(mu, 0.1 * (1000 / d2 + 30))


def test_dead_time_is_paralyzable_on_total_rate():
    f = frames([[5, 5, 1]])
    tau = 1e-4
    mu = MeasurementModel(scenario(), ["dead_time"]).expected_counts({**SRC, "dead_time.tau_s": tau}, f)
    n = 1030.0
    assert np.isclose(mu[0], 0.1 * n * np.exp(-n * tau))


def test_wall_attenuation_uses_path_length():
    wall = Wall((0.0, 3.0), (10.0, 3.0), 0.2, 3.0)
    f = frames([[5, 1, 0.0], [5, 4, 0.0]])  # first frame behind the wall, second in front
    m = MeasurementModel(scenario([wall]), ["wall_attenuation"])
    th = {**SRC, "background_cps": 0.0, "wall_attenuation.mu_per_m": 3.0}
    mu = m.expected_counts(th, f)
    assert np.isclose(mu[0], 0.1 * 1000 / 16 * np.exp(-3.0 * 0.2))
    assert np.isclose(mu[1], 0.1 * 1000 / 1)


def test_anisotropy_reduces_only_behind_the_detector():
    f = frames([[4, 5, 0.0], [6, 5, 0.0]], yaw=np.array([0.0, 0.0]))  # axis +x; source ahead, then behind
    m = MeasurementModel(scenario(), ["anisotropy"])
    th = {**SRC, "background_cps": 0.0, "anisotropy.fraction": 0.5, "anisotropy.half_angle_deg": 30.0}
    mu = m.expected_counts(th, f)
    cone = 0.5 * (1 - np.tanh((0.0 - 30.0) / 4.0))
    assert np.isclose(mu[0], 100.0, rtol=1e-6)
    assert np.isclose(mu[1], 100.0 * (1 - 0.5 * cone))


def test_air_attenuation_second_source_gradient_and_drift():
    f = frames([[5, 8, 0.0]], t=np.array([100.0]))
    sc = scenario()
    air = MeasurementModel(sc, ["air_attenuation"]).expected_counts({**SRC, "air_attenuation.mu_per_m": 0.01}, f)
    assert np.isclose(air[0], 0.1 * (1000 / 9 * np.exp(-0.03) + 30))
    two = MeasurementModel(sc, ["second_source"]).expected_counts(
        {**SRC, "second_source.x": 5.0, "second_source.y": 10.0, "second_source.cps_at_1m": 400.0}, f
    )
    assert np.isclose(two[0], 0.1 * (1000 / 9 + 400 / 4 + 30))
    grad = MeasurementModel(sc, ["background_gradient"]).expected_counts(
        {**SRC, "background_gradient.gx": 2.0, "background_gradient.gy": -1.0}, f
    )
    assert np.isclose(grad[0], 0.1 * (1000 / 9 + 30 + 2 * 5 - 8))
    # recorded = true + v t: recorded y = 8 at t = 100 with vy = 0.01 means the true y is 7
    drift = MeasurementModel(sc, ["pose_drift"]).expected_counts({**SRC, "pose_drift.vy": 0.01}, f)
    assert np.isclose(drift[0], 0.1 * (1000 / 4 + 30))


def test_a_source_carried_off_from_t0_is_the_still_source_before_and_the_moved_one_after():
    """source_motion: until t0 the counts are the still source's; after it, those of a source at
    src0 + v (t - t0), for scalar and vectorised hypotheses alike."""
    sc = scenario()
    t = np.array([10.0, 20.0, 30.0, 40.0])
    f = frames([[5, 5, 1]] * 4, t=t)
    th = {**SRC, "source_motion.vx": 0.1, "source_motion.vy": -0.05, "source_motion.t0": 20.0}
    mu = MeasurementModel(sc, ["source_motion"]).expected_counts(th, f)
    moved = np.maximum(t - 20.0, 0.0)
    d2 = (0.1 * moved) ** 2 + (0.05 * moved) ** 2 + 1.0
    assert np.allclose(mu, 0.1 * (1000 / d2 + 30))
    many = MeasurementModel(sc, ["source_motion"]).expected_counts({**th, "source_motion.vx": np.array([0.1, 0.0])}, f)
    assert np.allclose(many[0], mu) and np.allclose(many[1], 0.1 * (1000 / ((0.05 * moved) ** 2 + 1.0) + 30))
    assert MeasurementModel(sc, ["source_motion"]).param("source_motion.t0").fixed


def test_a_drifting_background_follows_its_sine_and_ramp_in_time():
    t = np.array([5.0, 10.0, 15.0, 20.0])
    f = frames([[50, 50, 1]] * 4, t=t)  # far from the source: background alone (to 1e-3)
    th = {**SRC, "cps_at_1m": 0.0, "background_drift.amplitude": 0.4, "background_drift.period_s": 20.0,
          "background_drift.phase": 0.5, "background_drift.percent_per_min": 30.0}
    mu = MeasurementModel(scenario(), ["background_drift"]).expected_counts(th, f)
    assert np.allclose(mu, 0.1 * 30 * (1 + 0.4 * np.sin(2 * np.pi * t / 20 + 0.5) + 30 / 100 * t / 60))


def test_vectorised_hypotheses_match_one_at_a_time():
    wall = Wall((0.0, 3.0), (10.0, 3.0), 0.2, 3.0)
    rng = np.random.default_rng(1)
    f = frames(rng.uniform([0, 0, 1], [10, 10, 2], size=(40, 3)), yaw=rng.uniform(-np.pi, np.pi, 40))
    m = MeasurementModel(scenario([wall]), ["dead_time", "wall_attenuation", "anisotropy", "second_source"])
    xs = rng.uniform(0, 10, 7)
    th = {**SRC, "x": xs, "dead_time.tau_s": 1e-5, "wall_attenuation.mu_per_m": 2.0, "second_source.x": 2.0,
          "second_source.y": 7.0, "second_source.cps_at_1m": 300.0}
    many = m.expected_counts(th, f)
    assert many.shape == (7, 40)
    for i, x in enumerate(xs):
        assert np.allclose(many[i], m.expected_counts({**th, "x": x}, f))


def test_bad_effect_names_and_spectral_only_effects_are_refused():
    with pytest.raises(ValueError, match="unknown effect"):
        MeasurementModel(scenario(), ["dark_matter"])
    with pytest.raises(ValueError, match="spectrum"):
        MeasurementModel(scenario(), ["gain_drift"])
    with pytest.raises(KeyError, match="no parameter"):
        MeasurementModel(scenario()).expected_counts({"tau": 1.0}, frames([[1, 1, 1]]))


def test_photopeak_window_uses_only_its_channels(shared_datasets):
    from estimator.localizers.base import make_localizer
    from radseek_io.truth import read_dataset_with_truth

    ds = read_dataset_with_truth(shared_datasets / "lattice-wall")
    k = MeasurementModel.window_channels(ds.scenario, 600, 720)
    edges = ds.scenario.channel_edges_keV
    assert all(edges[i] < 720 and edges[i + 1] > 600 for i in k) and len(k) == 3
    m = MeasurementModel(ds.scenario, ["wall_attenuation"], channels=k)
    assert np.array_equal(m.observed_counts(ds.frames), ds.frames.counts[:, list(k)].sum(1))
    # the window fit localises the same source from ~1/3 of the counts; its cps_at_1m is the peak's share
    total = make_localizer("mle", effects=("wall_attenuation",), n_starts=3).fit(ds)
    peak = make_localizer("mle", effects=("wall_attenuation",), n_starts=3, energy_window_keV=(600, 720)).fit(ds)
    s = ds.truth.sources[0]
    assert np.hypot(peak.sources_[0]["x"] - s.x, peak.sources_[0]["y"] - s.y) < 0.15
    assert 0.1 < peak.sources_[0]["cps_at_1m"] / total.sources_[0]["cps_at_1m"] < 0.6
    with pytest.raises(ValueError, match="no channel"):
        MeasurementModel.window_channels(ds.scenario, 5000, 6000)


def test_the_operators_air_is_fixed_physics_in_every_model():
    """scenario ``air_mu_per_m``: the baseline times exp(-mu d), mu fixed (not fitted); a caller that fits
    air_attenuation itself gets it free."""
    import dataclasses

    f = frames([[5, 5, 1], [5, 5, 2], [8, 9, 0]])
    d = np.array([1.0, 2.0, 5.0])
    air = dataclasses.replace(scenario(), air_mu_per_m=0.0093)
    m = MeasurementModel(air)
    assert m.free_names == MeasurementModel(scenario()).free_names
    assert np.allclose(m.expected_counts(SRC, f), 0.1 * (1000 / d**2 * np.exp(-0.0093 * d) + 30))
    assert "air_attenuation.mu_per_m" in MeasurementModel(air, effects=("air_attenuation",)).free_names


def test_wall_edges_are_ramps_of_the_crystals_size():
    """The model's walls have edges ``EDGE_M`` (1 cm) wide: far from an edge the path length is the hard slab's
    (radseek.geometry.path_lengths, the emulator's), within a few EDGE_M of one it differs by at most EDGE_M,
    and across a shadow edge it is a smooth ramp: its slope along the detector's path changes over centimetres,
    where the hard slab's jumps between two 0.5 mm steps (the jump that made the walled fits crawl)."""
    from estimator.model import WallAttenuation, _SlabFrame
    from radseek.geometry import path_lengths, wall_arrays

    wall = Wall((4.0, 3.0), (6.0, 3.0), 0.2, 3.0)
    arr = wall_arrays([wall])
    src = np.array([5.0, 5.0, 0.0])
    rng = np.random.default_rng(3)
    pos = np.column_stack([rng.uniform(0, 10, 4000), rng.uniform(0, 10, 4000), rng.uniform(0.5, 2.5, 4000)])
    soft = _SlabFrame(arr, WallAttenuation.EDGE_M).lengths(pos, src)
    hard = path_lengths(pos, src, [wall])
    assert np.abs(soft - hard).max() < WallAttenuation.EDGE_M
    assert np.median(np.abs(soft - hard)[hard > 0.05]) < 1e-4  # far inside the shadow: the same length

    # the detector at 1.5 m height walks east along y = 0 across the shadow edge of the wall's east end
    xs = np.arange(7.2, 7.9, 5e-4)  # the shadow of the east end (x = 6) falls at x = 7.4-7.6 on y = 0
    walk = np.column_stack([xs, np.zeros_like(xs), np.full_like(xs, 1.5)])
    for length, jumps in ((_SlabFrame(arr, WallAttenuation.EDGE_M).lengths(walk, src), False),
                          (path_lengths(walk, src, [wall]), True)):
        slope = np.diff(length) / 5e-4
        assert slope.min() < -0.1  # the shadow does end along this walk
        assert (np.abs(np.diff(slope)).max() > 0.05) == jumps


def test_a_walled_model_evaluates_hypotheses_and_poses_alike():
    """Many source hypotheses at once (grid starts, particle filters) take the same smooth walls as one."""
    wall = Wall((0.0, 3.0), (10.0, 3.0), 0.2, 3.0)
    rng = np.random.default_rng(4)
    f = frames(rng.uniform([0, 0, 1], [10, 10, 2], size=(60, 3)))
    m = MeasurementModel(scenario([wall]), ["wall_attenuation"])
    ys = np.linspace(2.5, 3.5, 11)  # sources on both sides of the wall and inside it
    many = m.expected_counts({**SRC, "y": ys, "wall_attenuation.mu_per_m": 5.0}, f)
    one = np.array([m.expected_counts({**SRC, "y": y, "wall_attenuation.mu_per_m": 5.0}, f) for y in ys])
    np.testing.assert_allclose(many, one, rtol=1e-12)


def test_wall_lengths_asked_again_are_kept_and_never_stale():
    """A fit asks again for the lengths of the same source and poses (MIGRAD steps in strength, background and
    mu): those come back identical and read-only; another source, other poses or more sources than the memo holds
    are computed afresh (checked against the slab lengths computed directly)."""
    from estimator.model import WallAttenuation, _SlabFrame
    from radseek.geometry import wall_arrays

    walls = wall_arrays([Wall((0.0, 3.0), (10.0, 3.0), 0.2, 3.0)])
    rng = np.random.default_rng(6)
    pos = rng.uniform([0, 0, 1], [10, 10, 2], size=(300, 3))
    eff = WallAttenuation()
    direct = _SlabFrame(walls, WallAttenuation.EDGE_M)
    sources = [np.array([x, 5.0, 0.0]) for x in np.linspace(1, 9, WallAttenuation.MEMO_SIZE + 3)]
    for src in sources + sources[:2]:  # the first two were evicted by then
        for p in (pos, pos + 0.01):
            got = eff._lengths(p, src, walls)
            np.testing.assert_array_equal(got, direct.lengths(p, src))
            assert eff._lengths(p.copy(), src.copy(), walls) is got  # equal inputs: the kept array
            assert not got.flags.writeable


def _central_jacobian(m, th, f, h=1e-6):
    """d counts / d position offset by central differences (h small against every ramp)."""
    out = np.zeros((len(f), 3))
    for k in range(3):
        o = np.zeros((len(f), 3))
        o[:, k] = h
        out[:, k] = (m.expected_counts(th, f, offsets=o) - m.expected_counts(th, f, offsets=-o)) / (2 * h)
    return out


@pytest.mark.parametrize("effects", [("wall_attenuation",), ("unmapped_wall",), (
    "wall_attenuation", "unmapped_wall", "unmapped_wall_2", "dead_time", "air_attenuation", "anisotropy",
    "background_gradient", "pose_drift", "second_source", "source_motion", "background_drift")])
def test_the_analytic_position_jacobian_is_the_derivative_across_a_slabs_shadow(effects):
    """A detector crossing a slab's shadow at 1.5 m (source at the floor behind a wall at y = 3, east end at
    x = 6): its counts and their derivative in the position, from one evaluation, are the model's counts and
    their central differences, in the open, on the shadow's ramps (1 cm mapped, 8 cm unmapped) and behind it;
    and the wall is in the derivative (it differs from the wall-free model's inside the shadow)."""
    wall = Wall((4.0, 3.0), (6.0, 3.0), 0.2, 3.0)
    xs = np.r_[np.linspace(6.0, 9.0, 301), np.linspace(7.1, 7.4, 61)]  # the east end's shadow ends at x 7.14-7.37
    f = frames(np.column_stack([xs, np.full_like(xs, 0.5), np.full_like(xs, 1.5)]),
               yaw=np.linspace(-3.0, 3.0, len(xs)))
    m = MeasurementModel(scenario([wall]), effects)
    th = {**SRC, "wall_attenuation.mu_per_m": 5.0, "unmapped_wall.r": 2.0, "unmapped_wall.phi_deg": -90.0,
          "unmapped_wall.length": 2.0, "unmapped_wall.mu_per_m": 4.0, "unmapped_wall_2.r": 1.5,
          "unmapped_wall_2.phi_deg": 30.0, "dead_time.tau_s": 1e-4, "background_gradient.gx": 1.0,
          "pose_drift.vx": 0.01, "second_source.x": 8.0, "second_source.y": 2.0, "second_source.cps_at_1m": 300.0,
          "anisotropy.fraction": 0.4, "source_motion.vx": 0.02, "source_motion.vy": -0.01, "source_motion.t0": 10.0,
          "background_drift.amplitude": 0.3, "background_drift.period_s": 20.0, "background_drift.percent_per_min": 5.0}
    th = {k: v for k, v in th.items() if k in m.param_names}
    mu, jac = m.expected_counts_and_jacobian(th, f)
    np.testing.assert_allclose(mu, m.expected_counts(th, f), rtol=1e-12)
    fd = _central_jacobian(m, th, f)
    np.testing.assert_allclose(jac, fd, rtol=1e-5, atol=1e-6 * np.abs(fd).max())
    free = MeasurementModel(scenario(), tuple(e for e in effects if "wall" not in e))
    th_free = {k: v for k, v in th.items() if k in free.param_names}
    shaded = xs < 7.1
    jac_free = free.expected_counts_and_jacobian(th_free, f)[1][shaded]
    assert np.abs(jac[shaded] - jac_free).max() > 0.2 * np.abs(jac_free).max()
    # at offsets (the profile's later iterates) too
    off = np.random.default_rng(7).normal(0, 0.03, (len(f), 3))
    mu_o, jac_o = m.expected_counts_and_jacobian(th, f, offsets=off)
    np.testing.assert_allclose(mu_o, m.expected_counts(th, f, offsets=off), rtol=1e-12)
    h = 1e-6
    for k in range(3):
        e = np.zeros(3)
        e[k] = h
        col = (m.expected_counts(th, f, offsets=off + e) - m.expected_counts(th, f, offsets=off - e)) / (2 * h)
        np.testing.assert_allclose(jac_o[:, k], col, rtol=1e-5, atol=1e-6 * np.abs(col).max())
