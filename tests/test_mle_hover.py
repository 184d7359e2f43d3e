"""A fit searched on hover blocks (estimator.mle.hover_blocks, ``fit(hover=True)``): where the rate is the same across
each block the blocks' likelihood is the frames' up to a constant, so the search must find the frames' own optimum;
what it reports (-log L, deviance, expected counts, pose offsets) is the frames' own."""

import numpy as np
import pytest

from estimator.mle import HOVER_FRAMES, block_frames, fit, hover_blocks, poisson_nll
from radseek.dataset import Frames
from tests.test_mle import _walled_close_pass
from tests.test_mle_screen import _noisy_strong


def _frames(pos, yaw, dwell, vehicle=None, walk=None):
    n = len(dwell)
    pos = np.asarray(pos, dtype=float)
    return Frames(t=np.arange(n) * 0.1, duration=np.full(n, 0.1), x=pos[:, 0], y=pos[:, 1], z=pos[:, 2],
                  yaw=np.asarray(yaw, dtype=float), var_x=np.zeros(n), var_y=np.zeros(n), var_z=np.zeros(n),
                  dwell=np.asarray(dwell), counts=np.arange(n * 32).reshape(n, 32) % 7,
                  vehicle=None if vehicle is None else np.asarray(vehicle),
                  walk=None if walk is None else np.asarray(walk))


def test_a_still_dwell_is_cut_a_second_at_a_time_and_transit_frames_stay_single():
    pos = np.tile([2.0, 3.0, 1.5], (25 + 4, 1))
    pos[25:, 0] += 0.5 * np.arange(1, 5)  # transit after the dwell
    f = _frames(pos, np.zeros(29), [0] * 25 + [-1] * 4)
    block = hover_blocks(f)
    assert np.bincount(block).tolist() == [HOVER_FRAMES, HOVER_FRAMES, 5, 1, 1, 1, 1]
    b = block_frames(f, block)
    assert b.counts.sum(axis=0).tolist() == f.counts.sum(axis=0).tolist()  # nothing lost or counted twice
    assert np.allclose(b.duration[:3], [1.0, 1.0, 0.5]) and np.allclose(b.t[0], 0.45)


def test_a_block_ends_where_the_pose_moves_turns_or_another_walk_begins():
    n = 8
    pos = np.tile([2.0, 3.0, 1.5], (n, 1))
    pos[3:, 1] += 0.06  # a 6 cm step at frame 3
    assert np.bincount(hover_blocks(_frames(pos, np.zeros(n), [0] * n))).tolist() == [3, 5]
    spin = np.radians(4.5) * np.arange(n)  # a spin dwell, 45 deg/s: two frames a block
    assert np.bincount(hover_blocks(_frames(np.tile([2.0, 3.0, 1.5], (n, 1)), spin, [0] * n))).tolist() == [2] * 4
    # headings either side of +-180 deg are 2 deg apart, not 358; the mean heading is 180 deg, not 0
    wrap = np.radians([179.0, -179.0, 179.0, -179.0])
    f = _frames(np.tile([2.0, 3.0, 1.5], (4, 1)), wrap, [0] * 4)
    assert np.bincount(hover_blocks(f)).tolist() == [4]
    assert abs(abs(block_frames(f, hover_blocks(f)).yaw[0]) - np.pi) < 1e-9
    # a second vehicle, or a new walk of the same dwell label, starts a block
    still = np.tile([2.0, 3.0, 1.5], (6, 1))
    assert np.bincount(hover_blocks(_frames(still, np.zeros(6), [0] * 6, vehicle=[0, 0, 0, 1, 1, 1]))).tolist() \
        == [3, 3]
    assert np.bincount(hover_blocks(_frames(still, np.zeros(6), [0] * 6, walk=[0, 0, 1, 1, 1, 1]))).tolist() \
        == [2, 4]


@pytest.mark.parametrize("case", ["wall-free", "walled"])
@pytest.mark.parametrize("seed", [0, 1])
def test_the_search_on_hover_blocks_finds_the_frames_optimum(case, seed):
    """Still dwells (the rate is the same across each block): the same optimum to MIGRAD's tolerance (well inside the
    1-sigma), the same -log L (within MIGRAD's EDM, 1e-3 in -log L x a few), reported on the frames themselves."""
    if case == "walled":
        m, _, f, _ = _walled_close_pass(seed)
    else:
        m, f = _noisy_strong(seed)
    frames = fit(m, f, n_starts=3, seed=seed)
    blocks = fit(m, f, n_starts=3, seed=seed, hover=True)
    assert len(np.unique(hover_blocks(f))) * HOVER_FRAMES <= len(f)  # searched on a tenth of the rows
    assert frames.converged and blocks.converged
    for k in ("x", "y", "cps_at_1m"):
        assert abs(blocks.values[k] - frames.values[k]) < 0.05 * frames.errors[k], k
        assert abs(blocks.errors[k] / frames.errors[k] - 1) < 0.05, k  # HESSE on the blocks: the same curvature
    assert abs(blocks.nll - frames.nll) < 0.05
    assert blocks.expected.shape == (len(f),) and blocks.n_frames == len(f) and blocks.dof == frames.dof
    assert blocks.nll == pytest.approx(poisson_nll(m.observed_counts(f), blocks.expected)
                                       + 0.5 * (blocks.deviance - _deviance_only(m, f, blocks)), abs=1e-6)


def _deviance_only(m, f, r):
    """The Poisson deviance of the fit's expected counts (its reported deviance less the offsets' penalty)."""
    from estimator.mle import poisson_deviance

    return float(poisson_deviance(m.observed_counts(f), r.expected).sum())


def test_a_spin_dwell_is_one_block_a_second_unless_the_model_depends_on_the_heading():
    """A model without anisotropy is blind to the heading: a spin dwell's frames pool as a still dwell's do; with
    anisotropy in the model, two frames a block (45 deg/s against HOVER_TURN_DEG)."""
    from estimator.model import MeasurementModel
    from tests.test_mle import SCEN

    n = 40
    pos = np.tile([2.0, 3.0, 1.5], (n, 1))
    f = _frames(pos, np.radians(4.5) * np.arange(n), [0] * n)
    assert not MeasurementModel(SCEN).uses_heading and MeasurementModel(SCEN, ("anisotropy",)).uses_heading
    assert len(np.unique(hover_blocks(f, turn_deg=180.0))) == n // HOVER_FRAMES
    assert len(np.unique(hover_blocks(f))) == n // 2
