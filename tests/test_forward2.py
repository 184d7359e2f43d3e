"""The independent forward model (benchmarks.forward2): its own analytic checks, and that it is independent."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest

from benchmarks.forward2 import FlightSpec, simulate
from benchmarks.forward2.physics import (
    _paralyzable,
    _scene,
    back_cone,
    random_unmapped_wall,
    slab_lengths,
    source_term,
    unmapped_walls,
)
from benchmarks.forward2.spectra import (
    ANALYTIC,
    EDGES,
    Response,
    background_response,
    photon_lines,
    scatter_response,
    source_response,
    total_variation,
)
from radseek.dataset import Wall
from radseek_io.dataset import write_dataset
from radseek_io.truth import read_dataset_with_truth

PKG = Path(__file__).resolve().parents[1] / "benchmarks" / "forward2"


def test_it_imports_neither_the_emulator_nor_the_estimator():
    banned = ("detector_fw_sim", "estimator", "radseek.count_model", "radseek.geometry")
    for f in PKG.glob("*.py"):
        for node in ast.walk(ast.parse(f.read_text())):
            if isinstance(node, ast.ImportFrom | ast.Import):
                names = [node.module or ""] if isinstance(node, ast.ImportFrom) else [a.name for a in node.names]
                assert not any(n.startswith(b) for n in names for b in banned), (f.name, names)


def test_slab_lengths_through_a_wall():
    wall = [Wall((0.0, -2.0), (0.0, 2.0), 0.2, 2.0)]  # along y at x = 0, 0.2 m thick, 2 m high
    src = np.array([1.0, 0.0, 0.0])
    a = np.array([[-1.0, 0.0, 0.0], [-1.0, 1.0, 0.0], [-1.0, 0.0, 5.0], [-1.0, 5.0, 0.0], [0.5, 0.0, 0.0]])
    L = slab_lengths(a, src, wall)
    assert L[0] == pytest.approx(0.2)  # straight through
    assert L[1] == pytest.approx(0.2 / np.cos(np.arctan2(1.0, 2.0)))  # oblique: 0.2 / cos(theta)
    # from 5 m up: at the wall's far face (x = 0.1) the segment is still at z = 2.25 > 2, so it passes over
    assert L[2] == pytest.approx(0.0, abs=1e-12)
    # a segment from 3 m up crosses the top: it enters the far face at z = 3 - 3 * 0.55 = 1.35 and the near
    # face at z = 3 - 3 * 0.45 = 1.65, all below 2: the full oblique length inside
    L3 = slab_lengths(np.array([[-1.0, 0.0, 3.0]]), src, wall)[0]
    assert L3 == pytest.approx(0.2 * np.hypot(2.0, 3.0) / 2.0)
    assert L[3] == 0.0  # beyond the wall's end
    assert L[4] == 0.0  # both ends on the same side


def test_back_cone_reduces_only_behind():
    pos = np.zeros((2, 3))
    yaw = np.zeros(2)  # axis +x, back -x
    f_back = back_cone(pos[:1], yaw[:1], np.array([-3.0, 0.0, 0.0]), 0.5, 30.0, 4.0)
    f_front = back_cone(pos[:1], yaw[:1], np.array([3.0, 0.0, 0.0]), 0.5, 30.0, 4.0)
    assert f_back[0] == pytest.approx(0.5, abs=1e-4) and f_front[0] == pytest.approx(1.0, abs=1e-9)


def test_paralyzable_dead_time_matches_n_exp_minus_n_tau():
    rng = np.random.default_rng(3)
    n_rate, tau, T, frames = 20000.0, 1e-5, 0.1, 400
    n = rng.poisson(n_rate * T, frames)
    rec = _paralyzable(n, np.arange(frames) * T, np.full(frames, T), tau, rng)
    expect = n_rate * T * np.exp(-n_rate * tau)  # 1637.5 per frame
    # the mean over 400 frames: sd ~ sqrt(expect / 400) ~ 2 counts
    assert abs(rec.mean() - expect) < 5 * np.sqrt(expect / frames) + 2.0


def test_gain_moves_the_photopeak_up_and_the_channels_are_a_distribution():
    r = source_response("real")
    p = r.channel_probs(EDGES, np.array([1.0, 1.05]))
    assert np.all(p >= 0) and np.all(p.sum(1) <= 1 + 1e-12)
    assert int(np.argmax(p[0, 10:20])) + 10 == 13  # 662 keV sits in 637-687 keV
    assert int(np.argmax(p[1, 10:20])) + 10 == 14  # at +5 % gain it reads 695 keV
    assert p[1].sum() > p[0].sum()  # a higher gain lifts pulses over the 40 keV threshold
    # crystals differ from each other as real ones do (0.04-0.11 total variation over the 32 channels)
    assert 0.02 < total_variation(r, source_response("wide")) < total_variation(r, source_response("fill")) < 0.15
    assert total_variation(r, background_response()) > 0.2 and total_variation(r, scatter_response()) > 0.2


def test_counts_follow_the_rate_and_over_dispersion_adds_r2_mu2():
    ds = simulate(FlightSpec("lattice", {}, crystal="real"), seed=2)
    ds_od = simulate(FlightSpec("lattice", {"over_dispersion": {"rel_sd": 0.2}}, crystal="real"), seed=2)
    for d, r in ((ds, 0.0), (ds_od, 0.2)):
        f = d.frames
        far = f.dwell == 0  # the first dwell is the far background point: a nearly constant rate
        n = f.total_counts[far]
        mu = n.mean()
        # variance of the sample variance ~ 2 var^2 / N: allow 5 sd
        want = mu + r**2 * mu**2
        assert abs(n.var(ddof=1) - want) < 5 * want * np.sqrt(2 / len(n)), (r, n.var(), want)
    assert ds.truth.effects == {} and ds_od.truth.effects == {"over_dispersion": {"rel_sd": 0.2}}
    assert ds.frames.counts.shape[1] == 32 and np.all(np.diff(ds.frames.t) > 0)


def test_pose_drift_and_random_walk_show_in_the_recorded_poses():
    a = simulate(FlightSpec("lattice", {}), seed=4)
    b = simulate(FlightSpec("lattice", {"pose_drift": {"vx": 0.01, "vy": 0.0}}), seed=4)
    dx = b.frames.x - a.frames.x
    assert np.allclose(dx, 0.01 * (b.frames.t - b.frames.duration / 2), atol=1e-9)
    rw = simulate(FlightSpec("lawnmower", {}, pose_error="random_walk"), seed=4)
    assert rw.frames.var_x[-1] > 3 * rw.frames.var_x[0]  # the reported variance grows with distance flown


# ------------------------------------------------------------------------------- issue 30: an open world


def _dwell_point(seed: int, spec: FlightSpec, k: int) -> tuple[np.ndarray, np.ndarray]:
    """(source, the hover point of dwell k) of ``simulate(spec, seed)``'s scene."""
    scene, track = _scene(spec, np.random.default_rng(seed))
    return scene["src"], track.points[1:][track.dwell == k][0]


def test_unmapped_wall_multiplies_the_source_rate_by_exp_minus_mu_t_at_normal_incidence():
    wall = [Wall((0.0, -2.0), (0.0, 2.0), 0.2, 2.0, "unmapped")]
    fx = {"unmapped_wall": {"walls": [wall[0].to_dict()], "mu_per_m": 2.5}}  # mu t = 0.5
    pos = np.array([[-1.5, 0.0, 0.5], [-1.5, 1.0, 0.5], [1.5, 0.0, 0.5]])  # normal, oblique, same side
    src = np.array([1.0, 0.0, 0.5])
    bare, _ = source_term(pos, np.zeros(3), src, 1000.0, {}, [], [])
    shaded, _ = source_term(pos, np.zeros(3), src, 1000.0, fx, [], unmapped_walls(fx))
    ratio = shaded / bare
    assert ratio[0] == pytest.approx(np.exp(-0.5), rel=1e-12)
    cos = 2.5 / np.hypot(2.5, 1.0)  # the oblique line crosses 0.2 / cos of slab
    assert ratio[1] == pytest.approx(np.exp(-2.5 * 0.2 / cos), rel=1e-12)
    assert ratio[2] == 1.0


def test_unmapped_wall_shadows_a_seeded_dwell_by_exp_minus_mu_l_within_poisson_bounds():
    seed, spec = 7, FlightSpec("lattice", {})
    src, p = _dwell_point(seed, spec, 1)
    h = p[:2] - src[:2]
    u = h / np.linalg.norm(h)
    c = src[:2] + 0.5 * h  # a 6 m x 3 m slab square to the line of sight, half way: the whole dwell in its shadow
    along = np.array([-u[1], u[0]])
    t, mu = 0.2, 5.0  # mu t = 1
    w = {"start": list(c - 3 * along), "end": list(c + 3 * along), "thickness": t, "height": 3.0}
    fx = {"unmapped_wall": {"walls": [w], "mu_per_m": mu}}
    a, b = simulate(spec, seed), simulate(FlightSpec("lattice", fx), seed)
    dw = a.frames.dwell == 1
    bg = spec.background_cps * a.frames.duration[dw].sum()  # expected background counts (truth)
    n0, n1 = a.frames.total_counts[dw].sum(), b.frames.total_counts[dw].sum()
    # through a vertical slab square to the horizontal line of sight the path is t |d| / |d_h|
    d = np.array([*p[:2], p[2]]) - src
    want = np.exp(-mu * t * np.linalg.norm(d) / np.linalg.norm(d[:2]))
    got = (n1 - bg) / (n0 - bg)
    sd = np.sqrt(n1 + got**2 * n0) / (n0 - bg)
    assert abs(got - want) < 5 * sd, (got, want, sd)
    assert want < 0.4  # it is a real shadow: > 5 sd from no wall
    assert 1 - got > 5 * sd
    # dwells out of the shadow keep their rate: equal counts within Poisson
    scene, track = _scene(spec, np.random.default_rng(seed))
    hover = track.points[1:][track.dwell >= 0]
    lit = np.flatnonzero(slab_lengths(hover, src, unmapped_walls(fx)) == 0)
    assert len(lit) >= 3
    for k in track.dwell[track.dwell >= 0][lit]:
        m0, m1 = a.frames.total_counts[a.frames.dwell == k].sum(), b.frames.total_counts[b.frames.dwell == k].sum()
        assert abs(m1 - m0) < 5 * np.sqrt(m0 + m1), (k, m0, m1)


def test_unmapped_wall_is_absent_from_the_scenario_and_in_truth_in_the_contract_form(tmp_path):
    spec = FlightSpec("lattice", {})
    fx = {"unmapped_wall": random_unmapped_wall(spec, 11, 0.3, np.random.default_rng(0), n_walls=3)}
    ds = simulate(FlightSpec("lattice", fx), 11)
    walls = ds.truth.effects["unmapped_wall"]["walls"]
    assert ds.scenario.walls == () and 1 <= len(walls) <= 3
    mu = ds.truth.effects["unmapped_wall"]["mu_per_m"]
    for w in walls:
        assert {"start", "end", "thickness", "height"} <= set(w) and len(w["start"]) == len(w["end"]) == 2
        assert mu * w["thickness"] == pytest.approx(0.3)
        assert 1.5 <= np.hypot(*np.subtract(w["end"], w["start"])) <= 4.0
        centre = (np.asarray(w["start"]) + np.asarray(w["end"])) / 2
        assert 0.6 - 1e-9 <= np.linalg.norm(centre - ds.truth.sources[0].position[:2]) <= 2.5 + 1e-9
    # the slabs shade part of the flight, not all of it
    L = slab_lengths(ds.frames.positions, ds.truth.sources[0].position, unmapped_walls(ds.truth.effects))
    assert 0.03 < np.mean(L > 0) < 0.8
    back = read_dataset_with_truth(write_dataset(tmp_path / "uw", ds.frames, ds.scenario, ds.truth))
    assert back.scenario.walls == () and back.truth.effects["unmapped_wall"] == ds.truth.effects["unmapped_wall"]


def test_unmap_walls_moves_the_geometry_walls_from_the_scenario_to_truth():
    mapped = simulate(FlightSpec("lshape", {"wall_attenuation": {"mu_per_m": 3.0}}), 5)
    hidden = simulate(FlightSpec("lshape", {"unmapped_wall": {"mu_per_m": 3.0}}, unmap_walls=True), 5)
    assert len(mapped.scenario.walls) == 2 and hidden.scenario.walls == ()
    assert hidden.truth.effects["unmapped_wall"] == {"mu_per_m": 3.0,
                                                     "walls": [w.to_dict() for w in mapped.scenario.walls]}
    assert np.array_equal(mapped.frames.counts, hidden.frames.counts)  # the same slabs, the same shadow
    with pytest.raises(ValueError, match="mu_per_m"):
        simulate(FlightSpec("wall", {}, unmap_walls=True), 5)
    # mapped walls stay in the scenario beside an unmapped one, which alone is in truth's unmapped_wall
    extra = {"start": [0.5, 0.5], "end": [0.5, 2.5], "thickness": 0.2, "height": 2.0}
    both = simulate(FlightSpec("lshape", {"wall_attenuation": {"mu_per_m": 3.0},
                                          "unmapped_wall": {"walls": [extra], "mu_per_m": 1.0}}), 5)
    assert both.scenario.walls == mapped.scenario.walls
    assert both.truth.effects["unmapped_wall"]["walls"] == [{**extra, "material": "unmapped"}]


@pytest.mark.parametrize("nuclide", ["Co-60", "Eu-152", "Ba-133"])
def test_second_source_of_another_nuclide_has_its_measured_spectrum(nuclide):
    """Counts above 1099 keV (channels 22-31): the Cs-137 primary puts none there (its net spectrum ends at the
    photopeak), so they are background plus the second source's share of its measured spectrum."""
    ss = {"x": 1.5, "y": 1.5, "z": 0.0, "cps_at_1m": 1300.0}
    cs = simulate(FlightSpec("lattice", {"second_source": ss}), 9)
    ds = simulate(FlightSpec("lattice", {"second_source": {**ss, "nuclide": nuclide}}), 9)
    assert ds.truth.effects["second_source"]["nuclide"] == nuclide and ds.scenario.nuclide == "Cs-137"
    f = ds.frames
    d2 = np.sum((f.positions - np.array([1.5, 1.5, 0.0])) ** 2, axis=1)
    p2 = source_response("real", nuclide=nuclide).channel_probs(EDGES, np.ones(1))[0]
    pb = background_response().channel_probs(EDGES, np.ones(1))[0]
    want = float(np.sum(f.duration * (1300.0 / d2 * p2[22:].sum() / p2.sum() + 30.0 * pb[22:].sum() / pb.sum())))
    got = f.counts[:, 22:].sum()
    # Poisson, plus the recorded pose's few cm at >= 1 m (<= 10 % of the rate)
    assert abs(got - want) < 5 * np.sqrt(want) + 0.1 * want, (got, want)
    if nuclide == "Co-60":  # 1173 and 1332 keV: ten times Cs-137's count up there
        assert got > 10 * cs.frames.counts[:, 22:].sum()


def test_a_co60_primary_is_in_the_scenario_and_truth(tmp_path):
    ds = simulate(FlightSpec("lattice", {}, nuclide="Co-60"), 3)
    cs = simulate(FlightSpec("lattice", {}), 3)
    assert ds.scenario.nuclide == "Co-60" and ds.truth.sources[0].nuclide == "Co-60"
    back = read_dataset_with_truth(write_dataset(tmp_path / "co", ds.frames, ds.scenario, ds.truth))
    assert back.scenario.nuclide == "Co-60" and back.truth.sources[0].nuclide == "Co-60"
    # cps_at_1m counts all channels at unit gain for every nuclide: the totals agree within Poisson (same flight)
    n_co, n_cs = ds.frames.total_counts.sum(), cs.frames.total_counts.sum()
    assert abs(n_co - n_cs) < 5 * np.sqrt(n_co + n_cs)
    assert ds.frames.counts[:, 22:].sum() > 20 * cs.frames.counts[:, 22:].sum()


def test_photon_lines_come_from_pydecay_with_short_lived_daughters():
    e, y = photon_lines("Cs-137")
    k = int(np.argmin(np.abs(e - 661.657)))
    assert e[k] == pytest.approx(661.657) and y[k] == pytest.approx(0.944 * 0.8974, rel=0.01)
    e, y = photon_lines("Co-60")
    assert e == pytest.approx([1173.23, 1332.49], abs=0.01)  # pydecay's two lines above 30 keV and 0.1 %
    assert y == pytest.approx([1.0, 1.0], abs=0.002)


def _peak_sd(r: Response, e: float, sigma: float) -> float:
    mid = (r.lo + r.hi) / 2
    w = np.abs(mid - e) < 2.5 * sigma
    m = r.mass[w]
    mean = np.sum(m * mid[w]) / m.sum()
    return float(np.sqrt(np.sum(m * (mid[w] - mean) ** 2) / m.sum()))


def test_analytic_crystals_differ_from_the_measured_one_and_scale_resolution_as_sqrt_e():
    real = source_response("real")
    a, b = source_response("analytic-a"), source_response("analytic-b")
    assert total_variation(real, a) > 0.08 and total_variation(real, b) > 0.08 and total_variation(a, b) > 0.08
    # FWHM = fwhm * 662 * sqrt(E / 662): 1332.5 keV's peak is sqrt(1332.5 / 661.7) = 1.42 times 662 keV's
    co = source_response("analytic-a", nuclide="Co-60")
    s662 = ANALYTIC["analytic-a"]["fwhm"] * 662.0 / 2.3548
    s1332 = s662 * np.sqrt(1332.492 / 661.657)
    ratio = _peak_sd(co, 1332.492, s1332) / _peak_sd(a, 661.657, s662)
    assert ratio == pytest.approx(np.sqrt(1332.492 / 661.657), rel=0.03)
    # the 662 keV peak holds its share: truncated at +-2.5 sd its width is 0.955 sigma (plus the 3 keV bins)
    assert _peak_sd(a, 661.657, s662) == pytest.approx(0.955 * np.hypot(s662, 3 / np.sqrt(12)), rel=0.03)
    # usable for a flight: analytic-a's sharper photopeak puts ~twice the real crystal's share in 637-687 keV
    shares = []
    for crystal in ("analytic-a", "real"):
        c = simulate(FlightSpec("lattice", {}, crystal=crystal), 2).frames.counts
        shares.append(c[:, 13].sum() / c.sum())
    assert shares[0] > 1.5 * shares[1]


def test_moving_source_counts_follow_the_moving_position_not_the_start():
    v = (0.04, -0.03)
    ds = simulate(FlightSpec("lattice", {"moving_source": {"vx": v[0], "vy": v[1]}}), 6)
    assert ds.truth.effects == {"moving_source": {"vx": 0.04, "vy": -0.03}}
    f, s0 = ds.frames, ds.truth.sources[0].position
    tm = f.t - f.duration / 2
    moving = s0 + np.column_stack([v[0] * tm, v[1] * tm, 0 * tm])
    off = 0
    for k, n, exp_mov, exp_fix, _ in _dwell_counts(f, moving, s0):
        # Poisson plus the recorded pose's ~5 cm at >= 1 m (<= 12 % of the rate)
        assert abs(n - exp_mov) < 5 * np.sqrt(exp_mov) + 0.12 * exp_mov, (k, n, exp_mov)
        off += abs(n / exp_fix - 1) > 0.3
    assert off >= 3  # the source moved 2-4 m during the flight: a fixed source misses several dwells


def _dwell_counts(f, src_t: np.ndarray, s0: np.ndarray):
    """Per dwell (k >= 1): observed counts, expected with the source at ``src_t`` (per frame) and at ``s0``
    (2,000 cps at 1 m over 30 cps), and the dwell's last frame mid-time."""
    tm = f.t - f.duration / 2
    for k in range(1, int(f.dwell.max()) + 1):
        w = f.dwell == k
        exp = [np.sum(f.duration[w] * (2000.0 / np.sum((f.positions[w] - s) ** 2, 1) + 30.0))
               for s in (src_t[w], s0)]
        yield k, f.total_counts[w].sum(), exp[0], exp[1], tm[w].max()


def test_background_drift_sine_and_ramp():
    amp, period = 0.4, 25.0
    ds = simulate(FlightSpec("lattice", {"background_drift": {"amplitude": amp, "period_s": period}},
                             cps_at_1m=0.0), 8)
    assert ds.truth.effects["background_drift"] == {"amplitude": amp, "period_s": period}
    f = ds.frames
    tm = f.t - f.duration / 2
    y = f.total_counts / (30.0 * f.duration) - 1  # relative deviation of the background
    X = np.column_stack([np.ones_like(tm), np.sin(2 * np.pi * tm / period), np.cos(2 * np.pi * tm / period)])
    coef = np.linalg.lstsq(X, y, rcond=None)[0]
    sd = np.sqrt(2 / len(y) / (30.0 * 0.1))  # per-frame relative variance 1 / (B dt), half the frames per term
    assert abs(coef[1] - amp) < 5 * sd and abs(coef[2]) < 5 * sd and abs(coef[0]) < 5 * sd
    ramp = simulate(FlightSpec("lattice", {"background_drift": {"percent_per_min": 30.0}}, cps_at_1m=0.0), 8)
    f = ramp.frames
    tm = f.t - f.duration / 2
    want = np.sum(30.0 * (1 + 0.3 * tm / 60) * f.duration)
    got = f.total_counts.sum()
    assert abs(got - want) < 5 * np.sqrt(want)
    assert abs(got - np.sum(30.0 * f.duration)) > 10 * np.sqrt(want)  # the ramp is far outside a flat background


def test_a_source_carried_off_mid_flight_stays_put_until_it_is_picked_up():
    v, start = (0.05, 0.0), 0.5
    ds = simulate(FlightSpec("lattice", {"moving_source": {"vx": v[0], "vy": v[1], "start_fraction": start}}), 6)
    f, s0 = ds.frames, ds.truth.sources[0].position
    tm = f.t - f.duration / 2
    t0 = start * (f.t.max() + 0.05)  # the track's duration, to a frame
    moved = np.maximum(tm - t0, 0.0)
    carried = s0 + np.column_stack([v[0] * moved, v[1] * moved, 0 * tm])
    early_off = late_off = 0
    for k, n, exp_car, exp_fix, t_last in _dwell_counts(f, carried, s0):
        assert abs(n - exp_car) < 5 * np.sqrt(exp_car) + 0.12 * exp_car, (k, n, exp_car)
        bad = abs(n / exp_fix - 1) > 0.3
        if t_last < t0:
            early_off += bad
        else:
            late_off += bad
    assert early_off == 0  # before it is picked up the fixed source explains every dwell
    assert late_off >= 2  # carried 2-3 m afterwards: the start position misses dwells
