"""The 32-channel spectral model: response matrix, and gain drift found in the spectrum (not in the totals)."""

from __future__ import annotations

import numpy as np
import pytest

from estimator.spectral import SpectralModel, energy_bins, response
from radseek_io.dataset import read_dataset

EDGES = np.r_[40.0, np.linspace(83.0, 1600.0, 31), 3000.0]


def test_response_at_unit_gain_is_the_identity_except_below_threshold():
    M = response(EDGES, np.array([1.0]))[0]
    lo, hi = energy_bins(EDGES)
    expected = np.eye(32)
    expected[0, 0] = (EDGES[1] - EDGES[0]) / (hi[0] - lo[0])  # the extension below 40 keV is not recorded
    assert np.allclose(M, expected)


def test_rising_gain_moves_mass_to_higher_channels_and_lifts_pulses_over_the_threshold():
    M = response(EDGES, np.array([1.05]))[0]
    # energy bin 13 now records partly in channel 14
    assert M[14, 13] > 0 and M[13, 13] < 1
    # every column keeps its mass unless it leaves the recorded range
    assert np.allclose(M[:, 1:].sum(0), 1.0)
    assert M[:, 0].sum() > response(EDGES, np.array([1.0]))[0][:, 0].sum()


def _synthetic(pct: float, seed: int, n_groups: int = 30) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    lo, hi = energy_bins(EDGES)
    centre = (lo + hi) / 2
    src = np.exp(-0.5 * ((centre - 662) / 25) ** 2) * 5 + np.where(centre < 477, 0.6, 0.02)
    bkg = np.exp(-centre / 400) + 0.05 * np.exp(-0.5 * ((centre - 1460) / 40) ** 2)
    src, bkg = src / src.sum(), bkg / bkg.sum()
    t = np.linspace(0, 600, n_groups)
    w = rng.uniform(0.05, 0.9, n_groups)
    M = response(EDGES, 1 + pct / 100 * t / 60)
    total = 20000
    p = w[:, None] * (M @ src) / (M @ src).sum(1, keepdims=True) + (1 - w[:, None]) * (M @ bkg) / (
        M @ bkg).sum(1, keepdims=True)
    return rng.poisson(total * p), t


class _FakeFrames:
    """Just what SpectralModel reads: one frame per group."""

    def __init__(self, counts: np.ndarray, t: np.ndarray):
        self.counts = counts
        self.t = t
        self.total_counts = counts.sum(1)


@pytest.mark.parametrize("pct", [0.0, 0.5])
def test_gain_drift_recovered_on_a_synthetic_mixture(pct):
    counts, t = _synthetic(pct, seed=4)
    fit = SpectralModel(EDGES).fit(_FakeFrames(counts, t), labels=np.arange(len(t)))
    if pct == 0:
        assert fit.lr < 10.8  # chi2_1 at p = 0.001
    else:
        assert fit.p_value < 1e-6
        assert abs(fit.percent_per_min - pct) < 4 * fit.error + 0.05


@pytest.mark.slow
def test_gain_drift_found_in_an_emulated_flight_and_absent_from_the_clean_shared_one(shared_datasets):
    from detector_fw_sim.scene import load_scene
    from detector_fw_sim.simulate import simulate_flight

    ds = simulate_flight(load_scene().without_effects().with_effect("gain_drift", percent_per_min=1.0),
                         path="lattice", seed=5)
    fit = SpectralModel(ds.scenario.channel_edges_keV).fit(ds.frames)
    assert fit.p_value < 1e-4, fit
    assert 0.5 < fit.percent_per_min < 1.5
    clean = read_dataset(shared_datasets / "lattice-clean")
    fit0 = SpectralModel(clean.scenario.channel_edges_keV).fit(clean.frames)
    assert fit0.p_value > 1e-3
