"""The unmapped wall: its geometry (analytic cases), the shadow screen, and diagnose naming it on a flight from the
independent forward model (``benchmarks.forward2``) whose wall is not in the scenario."""

from __future__ import annotations

import math

import numpy as np
import pytest

from estimator.diagnose.shadow import candidate_walls, score_placements, thin_slab_lengths
from estimator.model import MeasurementModel, UnmappedWall
from radseek.dataset import Frames, Scenario
from radseek.geometry import path_lengths_per_wall

EDGES = np.linspace(40.0, 3000.0, 33)


def _scenario() -> Scenario:
    return Scenario(channel_edges_keV=EDGES, background_cps=30.0, source_z=0.0, bounds_min=np.array([0.0, 0.0, 0.0]),
                    bounds_max=np.array([10.0, 8.0, 0.5]), walls=())


def _frames(pos: np.ndarray, t: np.ndarray | None = None) -> Frames:
    n = len(pos)
    z = np.zeros(n)
    return Frames(t=np.arange(1, n + 1) * 0.1 if t is None else t, duration=np.full(n, 0.1), x=pos[:, 0],
                  y=pos[:, 1], z=pos[:, 2], yaw=z, var_x=z, var_y=z, var_z=z, dwell=np.arange(n),
                  counts=np.zeros((n, 32), dtype=np.int64))


def test_wall_of_and_placement_round_trip():
    src = np.array([5.0, 4.0])
    vals = {"x": 5.0, "y": 4.0, "unmapped_wall.r": 1.5, "unmapped_wall.phi_deg": 30.0, "unmapped_wall.tilt_deg": 20.0,
            "unmapped_wall.length": 2.5, "unmapped_wall.thickness": 0.2, "unmapped_wall.height": 3.0}
    w = UnmappedWall.wall_of(vals)
    centre = (w[0:2] + w[2:4]) / 2
    assert np.hypot(*(centre - src)) == pytest.approx(1.5)
    assert np.hypot(*(w[2:4] - w[0:2])) == pytest.approx(2.5)
    # square to the bearing when tilt is 0: the wall's direction is perpendicular to source -> centre
    vals0 = {**vals, "unmapped_wall.tilt_deg": 0.0}
    w0 = UnmappedWall.wall_of(vals0)
    assert np.dot(w0[2:4] - w0[0:2], (w0[0:2] + w0[2:4]) / 2 - src) == pytest.approx(0.0, abs=1e-9)
    back = UnmappedWall.placement(w, src)
    for k in ("r", "phi_deg", "tilt_deg", "length"):
        assert back[k] == pytest.approx(vals[f"unmapped_wall.{k}"], abs=1e-9)
    # a slab through the source, or lying along the line of sight, is outside the effect's range
    assert UnmappedWall.placement(np.array([4.8, 4.0, 5.2, 4.0, 0.2, 3.0]), src) is None
    assert UnmappedWall.placement(np.array([6.0, 4.0, 8.0, 4.0, 0.2, 3.0]), src) is None


def test_model_attenuates_exactly_the_lines_of_sight_through_the_slab():
    """Normal incidence through a 0.2 m slab of mu 2.5 /m: factor exp(-0.5) behind it, 1 beside it (analytic)."""
    sc = _scenario()
    model = MeasurementModel(sc, effects=("unmapped_wall",))
    # source at (5, 4, 0); wall 1 m east, square to +x, 2 m long; detectors at z = 0 so the geometry is planar
    theta = {"x": 5.0, "y": 4.0, "cps_at_1m": 1000.0, "background_cps": 0.0, "unmapped_wall.r": 1.0,
             "unmapped_wall.phi_deg": 0.0, "unmapped_wall.tilt_deg": 0.0, "unmapped_wall.length": 2.0,
             "unmapped_wall.mu_per_m": 2.5}
    pos = np.array([[8.0, 4.0, 0.0], [8.0, 4.5, 0.0], [2.0, 4.0, 0.0], [5.0, 7.0, 0.0], [6.5, 7.5, 0.0]])
    f = _frames(pos)
    with_wall = model.expected_counts(theta, f)
    free = model.expected_counts({**theta, "unmapped_wall.mu_per_m": 0.0}, f)
    ratio = with_wall / free
    # behind the wall: the line of sight crosses 0.2 m at normal incidence (first) or 0.2 / cos(angle) (second);
    # the slab's faces are ramps EDGE_M wide (soft max / min), which lengthen a path by a small part of a ramp
    length = -np.log(ratio) / 2.5
    tol = 0.1 * UnmappedWall.EDGE_M
    assert length[0] == pytest.approx(0.2, abs=tol)
    cos = 3.0 / math.hypot(3.0, 0.5)
    assert length[1] == pytest.approx(0.2 / cos, abs=tol)
    assert length[1] > length[0]
    # west of the source, north of it, and past the wall's end (the line crosses x = 6 at y = 6.3 > 5): no shadow
    assert ratio[2:] == pytest.approx(1.0, abs=1e-4)  # the ramps' tails


def test_screen_lengths_match_the_slab_geometry_of_tall_thin_walls():
    """The screen's thin-slab lengths against radseek.geometry's slab method on random lines of sight."""
    rng = np.random.default_rng(3)
    walls = candidate_walls(np.array([2.0, 2.0]), np.array([7.0, 6.0]), spacing=1.0, n_angles=6, thickness=0.02,
                            height=50.0)
    pos = np.column_stack([rng.uniform(0, 10, 40), rng.uniform(0, 8, 40), rng.uniform(0.5, 2.5, 40)])
    src = np.array([5.0, 4.0, 0.0])
    # the placements the model can take (none through the source; the screen skips the others)
    walls = walls[[UnmappedWall.placement(w, src[:2]) is not None for w in walls]]
    got = thin_slab_lengths(pos, src, walls)  # (P, J)
    ref = path_lengths_per_wall(pos[:, None, :], src[None, None, :], walls)[:, 0, :].T  # (P, J)
    crossing = ref > 0
    # where both say the line crosses, the length agrees to the thin-slab approximation (a thickness of 2 cm) but
    # where the line grazes the slab or clips a corner (the exact slab cuts it short)
    both = crossing & (got > 0)
    assert both.sum() > 50
    close = np.abs(got[both] - ref[both]) <= 0.05 * ref[both] + 2e-3
    assert close.mean() > 0.9
    assert np.all(got[both] >= ref[both] - 2e-3)  # the thin-slab length is never short: a screen over-scores
    # the thin slab never shadows a line the exact slab misses; it misses only lines clipping an end's corner
    assert not np.any((got > 0) & ~crossing)
    missed = crossing & (got == 0)
    assert missed.sum() < 0.1 * crossing.sum()
    assert np.median(ref[missed]) < 0.02


def test_screen_finds_the_placement_of_a_known_shadow():
    """Expected counts of a 12-point ring around a source with one sector shadowed by exp(-0.6): the screen's best
    placement shadows exactly that sector, with an optical depth near 0.6."""
    ang = np.radians(np.arange(0, 360, 15))
    pos = np.column_stack([5 + 2.5 * np.cos(ang), 4 + 2.5 * np.sin(ang), np.full(len(ang), 1.5)])
    frames = _frames(np.repeat(pos, 40, axis=0), t=np.arange(1, 40 * len(ang) + 1) * 0.1)
    frames = Frames(**{**frames.__dict__, "dwell": np.repeat(np.arange(len(ang)), 40)})
    src = np.array([5.0, 4.0, 0.0])
    d2 = ((frames.positions - src) ** 2).sum(1)
    s = 5000.0 / d2 * 0.1
    shadowed = np.abs(np.degrees(np.arctan2(frames.y - 4, frames.x - 5))) < 40  # east, within +-40 deg
    counts_mean = 3.0 + s * np.where(shadowed, math.exp(-0.6), 1.0)
    rng = np.random.default_rng(0)
    counts = rng.poisson(counts_mean)
    frames = Frames(**{**frames.__dict__, "counts": np.column_stack([counts, np.zeros((len(counts), 31), int)])})
    expected = 3.0 + s * (counts.sum() - 3.0 * len(counts)) / s.sum()  # the best wall-free fit's strength
    walls = candidate_walls(np.array([3.0, 1.5]), np.array([7.5, 6.5]))
    pl = score_placements(frames, expected, np.full(len(counts), 3.0), src, walls)
    i = int(np.argmax(pl.lr))
    best = walls[i]
    centre = (best[0:2] + best[2:4]) / 2
    bearing = math.degrees(math.atan2(centre[1] - 4, centre[0] - 5))
    assert abs(bearing) < 25
    assert 0.4 <= pl.mu_t[i] <= 0.8
    assert pl.lr[i] > 100


@pytest.mark.slow
def test_diagnose_names_an_unmapped_wall_on_an_independent_flight(tmp_path):
    """forward2's straight wall, removed from the scenario (mu x t = 0.5): diagnose names unmapped_wall, its fit is
    adequate, its centre is within 0.5 m of the true slab, and the source error falls."""
    from benchmarks.forward2 import FlightSpec, simulate
    from estimator.diagnose.runner import diagnose
    from reporting.diagnose_report import json_report
    from reporting.truth_errors import score_diagnosis

    ds = simulate(FlightSpec(geometry="wall", effects={"unmapped_wall": {"mu_per_m": 2.5}}, unmap_walls=True,
                             dwell_s=5.0), seed=11)
    assert ds.scenario.walls == ()
    d = score_diagnosis(diagnose(ds, quiet=True, n_starts=2), ds.truth)
    j = json_report(d)
    assert "unmapped_wall" in j["missing"] and not j["unexplained"]
    truth = ds.truth.effects["unmapped_wall"]["walls"][0]
    a, b = np.array(truth["start"], float), np.array(truth["end"], float)
    dists = []
    for w in j["unmapped_walls"]:
        c = (np.array(w["start"]) + np.array(w["end"])) / 2
        t = np.clip(np.dot(c - a, b - a) / np.dot(b - a, b - a), 0, 1)
        dists.append(float(np.hypot(*(c - (a + t * (b - a))))))
    assert min(dists) < 0.5
    assert d.after.source_error_m < d.current.source_error_m
    # the distance the shadow allows along the wall's bearing holds the true centre's distance from the source
    w = j["unmapped_walls"][int(np.argmin(dists))]
    # the part of it the flight's lines of sight cross lies on it, and near the part of the true slab they cross
    from benchmarks.diagnose_evaluate import shaded_part

    seen = {k: np.array(v) for k, v in w["seen_part"].items()}
    assert segment_distance_to(seen["start"], w) < 2e-3 and segment_distance_to(seen["end"], w) < 2e-3  # rounded
    true_src = np.array([ds.truth.sources[0].x, ds.truth.sources[0].y])
    shaded = shaded_part(true_src, truth, np.c_[ds.frames.x, ds.frames.y])
    mid = (np.array(shaded["start"]) + np.array(shaded["end"])) / 2
    assert np.hypot(*((seen["start"] + seen["end"]) / 2 - mid)) < 0.5
    # the residual map draws it (as fitted, and its seen part)
    from estimator.diagnose.plots import plot_map

    assert plot_map(d.final, tmp_path / "map.png", ds.scenario).stat().st_size > 10_000
    src = np.array([d.final.fit.values["x"], d.final.fit.values["y"]])
    lo, hi = w["distance_range_95_m"]
    assert lo <= w["distance_from_source_m"] <= hi
    assert lo <= float(np.hypot(*((a + b) / 2 - src))) <= hi


def segment_distance_to(p: np.ndarray, wall: dict) -> float:
    a, b = np.array(wall["start"], float), np.array(wall["end"], float)
    t = np.clip(np.dot(p - a, b - a) / np.dot(b - a, b - a), 0, 1)
    return float(np.hypot(*(p - (a + t * (b - a)))))


def test_vectorised_placeable_agrees_with_the_effects_placement():
    """The screen's vectorised filter keeps exactly the slabs ``UnmappedWall.placement`` accepts."""
    from estimator.diagnose.shadow import placeable

    walls = candidate_walls(np.array([1.0, 0.5]), np.array([8.0, 7.0]), spacing=0.7)
    src = np.array([4.3, 3.9])
    want = np.array([UnmappedWall.placement(w, src) is not None for w in walls])
    assert 0 < want.sum() < len(walls)
    assert np.array_equal(placeable(walls, src), want)


#: a forward2 flight with three unmapped slabs (the evaluation's uwall-1-lattice-n3-s2)
THREE_SLABS = {"geometry": "lattice", "crystal": "real", "pose_error": "independent", "scatter": 0.02, "effects": {
    "unmapped_wall": {"mu_per_m": 6.458299141957979, "walls": [
        {"start": [3.675113232975293, 3.042704072578077], "end": [5.228943719176189, 5.178074716224824],
         "thickness": 0.15483952942087278, "height": 2.872098370350744},
        {"start": [4.827939270372039, 3.617980007964025], "end": [4.1985532586911996, 7.147020499715357],
         "thickness": 0.15483952942087278, "height": 2.1815887062921555},
        {"start": [4.374619396074916, 6.134060814793415], "end": [1.1951307979842873, 4.512199155942302],
         "thickness": 0.15483952942087278, "height": 2.6467042233278177}]}}}


def test_the_profiled_likelihood_is_smooth_when_one_wall_stands_for_three():
    """One unmapped wall fitted to a flight behind three slabs leaves dwells whose counts push their pose offsets
    past the profile's limit. The profiled -log L must still be smooth in the source's position: with a hard clip
    of the offsets it jumped by tens between points 0.1 mm apart (second differences -77..+115) and MIGRAD crawled
    16,000 calls on the second-source candidate of this flight. Here: second differences of the order the
    curvature makes them (the plain likelihood's are 1e-4), changing smoothly from point to point."""
    from benchmarks.forward2 import FlightSpec, simulate
    from estimator.diagnose.backend import split_transit_legs
    from estimator.mle import PoseGroups, _Likelihood, declared_pose_error

    ds = simulate(FlightSpec(**THREE_SLABS), seed=80402)
    frames = split_transit_legs(ds.frames)
    # the held wall and the point where the hard clip's search crawled (traced from the diagnose call)
    held = {"unmapped_wall.r": 0.4, "unmapped_wall.phi_deg": 44.632, "unmapped_wall.tilt_deg": 70.353,
            "unmapped_wall.length": 2.469}
    model = MeasurementModel(ds.scenario, ("unmapped_wall", "second_source")).with_params(
        **{k: {"value": v, "fixed": True} for k, v in held.items()})
    point = {"x": 2.725, "y": 5.18, "cps_at_1m": 1135.633, "background_cps": 10.237, "unmapped_wall.mu_per_m": 3.98,
             "second_source.x": 2.212, "second_source.y": 2.959, "second_source.cps_at_1m": 119.639}
    names = model.free_names
    groups = PoseGroups.from_frames(frames, declared_pose_error(model))
    fcn = _Likelihood(model, frames, names, {p.name: p.value for p in model.params if p.fixed}, groups)
    vals = [fcn(*[point[n] + (k * 1e-4 if n == "x" else 0.0) for n in names]) for k in range(-5, 6)]
    second = np.diff(vals, 2)
    assert np.abs(second).max() < 1.0
    assert np.abs(np.diff(second)).max() < 0.1
