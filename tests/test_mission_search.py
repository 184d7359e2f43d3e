"""The search brain flown in-process against the emulator, and the truth-isolation rule."""

import numpy as np
import pytest

from detector_fw_sim.scene import load_scene
from launch.offline import fly_offline
from mission.search import Phase, SearchConfig


@pytest.mark.parametrize("seed", [1, 2])
def test_search_finds_the_default_source(seed):
    r = fly_offline(load_scene(), SearchConfig(), seed=seed)
    assert r.decisions[-1].phase is Phase.DONE
    assert len(r.dwell_rates) <= SearchConfig().max_dwells
    # exploration ends only with three readings above background, then the estimate drives the search
    assert r.brain.search_dwells >= SearchConfig().min_search_dwells
    est = r.estimate
    # bound: the stop rule asks 1-sigma < 0.1 m; odometry drift (0.03 m/sqrt(m) over ~30 m, about 0.16 m)
    # adds an error the estimator cannot see, so 0.5 m is ~3 sigma of the two combined
    assert r.error_m < 0.5, (est, r.log)
    assert est["cps_at_1m"] == pytest.approx(1600, rel=0.25)
    # one sigma: the stop rule's is the estimate record's (estimator.inflight.sigma_m), which replay reproduces
    if r.decisions[-1].reason.startswith("source found"):
        assert est["sigma_m"] < SearchConfig().stop_sigma_m
        assert f"1-sigma {est['sigma_m']:.3f} m" in r.decisions[-1].reason
    # the recorded flight is a valid dataset whose dwell frames sit at the reported dwell positions
    f = r.dataset.frames
    for k, pos in enumerate(r.dwell_positions):
        m = f.dwell == k
        assert m.sum() >= 40  # >= t_min of 5 s at 10 Hz (fewer would mean frames were lost)
        assert np.allclose(f.positions[m].mean(0), pos, atol=0.05)
