"""Issue 36's target table (benchmarks/planner_error_time.py) on hand-made campaign rows: the paired comparison
and the verdicts say what the rows say."""

import numpy as np
import pytest

from benchmarks import planner_error_time as pet


def _row(scene, strategy, seed, error, time, covered=True, outcome="found", bound=0.1):
    return {"scene": scene, "strategy": strategy, "seed": seed, "status": "ok", "error_m": error,
            "mission_time_s": time, "covered_95": covered, "outcome": outcome, "bound_m": bound, "cpu_s": 1.0}


def test_paired_difference_and_time_ratio_over_the_common_seeds():
    info = [_row("s", "info", k, 0.10 + 0.01 * k, 50.0) for k in range(10)]
    lattice = [_row("s", "lattice", k, 0.12 + 0.01 * k, 100.0, outcome="pattern_flown") for k in range(12)]
    p = pet.paired(info, lattice, np.random.default_rng(0))
    assert p["n"] == 10  # seeds 10 and 11 flew only the lattice
    assert p["mean"] == pytest.approx(-0.02) and p["se"] == pytest.approx(0.0, abs=1e-12)
    assert p["better"] == 10 and p["time_ratio"] == pytest.approx(0.5)
    assert p["diff_ci"][0] <= p["diff_medians"] <= p["diff_ci"][1]


def test_the_verdicts_follow_the_targets():
    # info: 19 of 20 found, 19 of 20 covered (0.95), median error 0.105 m at bound 0.1 (<= 1.1 x), half the time
    info = [_row("s", "info", k, 0.1 + 0.001 * k, 50.0, covered=k > 0, outcome="found" if k else "budget_spent")
            for k in range(20)]
    # active: 2 of 20 covered (coverage out of the band), error 2 x the bound
    active = [_row("s", "active", k, 0.2, 90.0, covered=k < 2) for k in range(20)]
    lattice = [_row("s", "lattice", k, 0.2, 100.0, outcome="pattern_flown") for k in range(20)]
    lines = pet.report(info + active + lattice, np.random.default_rng(0))
    verdicts = {ln.split(" | ")[1]: ln for ln in lines if ln.startswith("| s | ") and " - lattice" not in ln
                and ("met |" in ln)}
    assert verdicts["info"].startswith("| s | info | met | met | met | 1.00 | 0.38 |")  # P(19 of 20) = 0.377
    assert verdicts["active"].startswith("| s | active | met | NOT met | NOT met | 0.00 | 0.38 |")
    pair = {ln.split(" | ")[1]: ln for ln in lines if " - lattice |" in ln}
    assert pair["info - lattice"].endswith("| met |")  # 0.105 <= 0.2 m at 0.5 x the time
    assert pair["active - lattice"].endswith("| NOT met |")  # as accurate, but at 0.9 x the time


def test_a_calibrated_ellipses_chance_of_the_coverage_band():
    """Analytic: of 20 calibrated ellipses, only 19 covered lands in [0.93, 0.97]: 20 x 0.95^19 x 0.05 = 0.377; at
    200 flights 0.860 and at 400 0.950 (the binomial's mass from 186 to 194 and from 372 to 388)."""
    assert pet.band_chance(20) == pytest.approx(20 * 0.95**19 * 0.05)
    assert pet.band_chance(200) == pytest.approx(0.860, abs=0.001)
    assert pet.band_chance(400) == pytest.approx(0.950, abs=0.001)
    assert pet.coverage_p(190, 200) == pytest.approx(1.0)  # the expected count
    assert pet.coverage_p(180, 200) < 0.05 < pet.coverage_p(185, 200)
