"""radseek localize says when its model fails, reports the pose-and-drift-aware bound, and pools long flights."""

import json
import math

import pytest

from radseek_cli import localize_cli


def _run(capsys, *argv):
    rc = localize_cli.main([*map(str, argv), "--quiet"])
    out = capsys.readouterr()
    return rc, out.out, out.err


def test_a_failing_fit_says_run_diagnose(shared_datasets, capsys):
    # lattice-wall without its wall: deviance/dof 1.4, p ~ 1e-26 (docs/localizers.md)
    rc, out, err = _run(capsys, shared_datasets / "lattice-wall", "--method", "mle", "--set", "n_starts=2")
    assert rc == 0
    assert "THE MODEL MISSES SOMETHING HERE" in out and "radseek diagnose" in out
    assert "goodness of fit p =" in err
    # with the wall the model fits: no such warning
    rc, out, err = _run(capsys, shared_datasets / "lattice-wall", "--method", "mle", "--set", "n_starts=2",
                        "--effects", "wall_attenuation")
    assert rc == 0 and "MISSES SOMETHING" not in out and "goodness of fit" not in err


def test_bound_is_reported_and_not_below_the_exact_pose_bound(shared_datasets, capsys):
    rc, out, _ = _run(capsys, shared_datasets / "lattice-clean", "--method", "mle", "--set", "n_starts=2", "--json")
    assert rc == 0
    r = json.loads(out)
    exact = math.hypot(r["crlb_std"][0][0], r["crlb_std"][0][1])
    assert r["bound_m"][0] >= exact > 0
    assert r["info"]["pose_error"] == "independent"  # the reference data's per-dwell offsets do not accumulate


def test_long_flights_are_pooled_and_say_so(shared_datasets, capsys):
    rc, out, _ = _run(capsys, shared_datasets / "lattice-clean", "--method", "mle", "--set", "n_starts=2", "--json")
    full = json.loads(out)
    rc, out, _ = _run(capsys, shared_datasets / "lattice-clean", "--method", "mle", "--set", "n_starts=2",
                      "--json", "--max-frames", "300")
    assert rc == 0
    pooled = json.loads(out)
    assert pooled["frames_fitted"] <= 300 < full["frames_fitted"]
    # pooling dwell frames loses only within-dwell jitter: the estimates agree within a fraction of a sigma
    for k, i in (("x", 0), ("y", 1)):
        sd = full["std"][0][i]
        assert pooled["sources"][0][k] == pytest.approx(full["sources"][0][k], abs=sd)
