"""The independent forward model (benchmarks.forward2): its own analytic checks, and that it is independent."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest

from benchmarks.forward2 import FlightSpec, simulate
from benchmarks.forward2.physics import _paralyzable, back_cone, slab_lengths
from benchmarks.forward2.spectra import EDGES, background_response, scatter_response, source_response, total_variation
from radseek.dataset import Wall

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
