"""Paper 003 eq. 6 gain: hand-computed values, limits, and the Fig. 4 setting."""

import numpy as np
import pytest

from planner.fig4 import FIG4_DWELLS, FIG4_SOURCE, fig4_grid
from planner.gain import GainConfig, gain_eq6, gain_eq6_as_printed, source_term

ORIGIN = np.zeros(3)


@pytest.mark.parametrize(
    ("node", "dwells", "cfg", "expected"),
    [
        # no dwell point, r = delta: u e^-u at u = 1 -> e^-1
        ([1.0, 0, 0], np.zeros((0, 3)), GainConfig(1.0, 1.85), 0.36787944117144233),
        # delta = 2, r = 1: u = 1/4 -> 0.25 e^-0.25
        ([0, 1.0, 0], np.zeros((0, 3)), GainConfig(2.0, 1.85), 0.19470019576785122),
        # one dwell 2 m away, zeta = 2 (the printed constant), N_d = 1: e^-1 (1 - e^-(4/2))
        ([1.0, 0, 0], [[1.0, 2.0, 0]], GainConfig(1.0, 2.0), 0.3180923728035784),
        # two dwells at squared distances 9 and 4, zeta N_d = 3.7: e^-1 (1 - e^-(9/3.7)) (1 - e^-(4/3.7))
        ([0, 1.0, 0], [[3.0, 1.0, 0], [0, -1.0, 0]], GainConfig(1.0, 1.85), 0.221735842964974),
    ],
)
def test_gain_matches_hand_computed_values(node, dwells, cfg, expected):
    g = gain_eq6(np.array([node]), ORIGIN, np.array(dwells, dtype=float), cfg)
    assert g.shape == (1,)
    assert g[0] == pytest.approx(expected, rel=1e-12)


def test_gain_vectorised_over_nodes_equals_one_by_one():
    rng = np.random.default_rng(3)
    nodes = rng.uniform(-3, 3, (50, 3))
    dwells = rng.uniform(-3, 3, (4, 3))
    src = rng.uniform(-1, 1, 3)
    all_at_once = gain_eq6(nodes, src, dwells)
    singly = np.array([gain_eq6(n[None], src, dwells)[0] for n in nodes])
    np.testing.assert_allclose(all_at_once, singly, rtol=1e-13)


def test_gain_is_zero_at_the_source_and_at_previous_dwell_points_and_bounded_by_1_over_e():
    dwells = np.array([[1.0, 0, 0], [0, 2.0, 0]])
    assert gain_eq6(ORIGIN[None], ORIGIN, dwells)[0] == 0.0
    assert np.all(gain_eq6(dwells, ORIGIN, dwells) == 0.0)
    rng = np.random.default_rng(0)
    g = gain_eq6(rng.uniform(-5, 5, (10_000, 3)), ORIGIN, dwells)
    assert np.all((g >= 0) & (g <= np.exp(-1)))


def test_source_term_peaks_at_delta():
    r = np.linspace(0.01, 5, 2001)
    for delta in (0.5, 1.0, 2.0):
        s = source_term(np.c_[r, 0 * r, 0 * r], ORIGIN, delta)
        assert r[np.argmax(s)] == pytest.approx(delta, abs=0.005)
        assert s.max() == pytest.approx(np.exp(-1), rel=1e-5)


def test_printed_form_would_prefer_revisiting_a_previous_dwell_point():
    """Why gain_eq6 uses 1 - exp(...): the literal printed factor attracts to old dwell points."""
    dwell = np.array([[1.0, 0, 0]])
    candidates = np.array([[1.0, 0, 0], [-1.0, 0, 0]])  # the old dwell point vs its mirror, both at r = delta
    printed = gain_eq6_as_printed(candidates, ORIGIN, dwell)
    ours = gain_eq6(candidates, ORIGIN, dwell)
    assert printed[0] > printed[1]
    assert ours[1] > ours[0] == 0.0


def test_fig4_setting_picks_a_point_away_from_all_previous_dwells_near_delta():
    xs, ys, g, best = fig4_grid(13)
    assert g.shape == (13, 13)
    # the best candidate is the grid argmax and lies farther from every previous dwell point than the source
    d_best = np.linalg.norm(FIG4_DWELLS - best, axis=1)
    d_src = np.linalg.norm(FIG4_DWELLS - FIG4_SOURCE, axis=1)
    assert np.all(d_best > d_src)
    # the source term alone peaks at r = delta = 1 m; repulsion pushes it out but not beyond 2 delta
    r = np.linalg.norm(best - FIG4_SOURCE)
    assert 1.0 <= r <= 2.0
    # it is in the quadrant without a dwell point (the source is at the centre, dwells in three corners)
    assert best[0] > FIG4_SOURCE[0] and best[1] > FIG4_SOURCE[1]


def test_gain_config_rejects_non_positive_factors():
    with pytest.raises(ValueError):
        GainConfig(delta=0.0)
    with pytest.raises(ValueError):
        GainConfig(zeta=-1.0)
