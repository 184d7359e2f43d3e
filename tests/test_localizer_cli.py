"""``radseek localize`` and ``radseek compare``: every method on the shared datasets, JSON contract, errors."""

from __future__ import annotations

import json

import numpy as np
import pytest

from benchmarks.analytic_flights import lattice_flight
from radseek_cli import compare_cli, localize_cli
from radseek_io.dataset import write_dataset
from reporting import truth_errors

FAST = {
    "pf": ["--set", "n_particles=5000"],
    "multi-pf": ["--set", "n_particles=1000"],
    "gp": ["--set", "n_restarts=1", "--set", "n_posterior_samples=20"],
    "mle": ["--set", "n_starts=1", "--set", "pose_uncertainty=false"],
    "sphere": [],
}


@pytest.mark.parametrize("method", list(FAST))
def test_every_method_runs_on_shared_dataset_json(method, shared_datasets, capsys):
    rc = localize_cli.main([str(shared_datasets / "lattice-clean"), "--method", method, "--json", *FAST[method]])
    assert rc == 0
    out = json.loads(capsys.readouterr().out)
    assert out["method"] == method
    assert {"x", "y", "z", "cps_at_1m"} <= set(out["sources"][0])
    assert len(out["covariance"]) == 4 * len(out["sources"])
    assert ("crlb" in out) and (out["crlb"] is not None) == (method in ("mle", "pf"))
    assert out["error"][0]["position_error_m"] < 0.5


def test_all_shared_datasets_with_sphere_and_text_output(shared_datasets, capsys):
    for name in sorted(p.name for p in shared_datasets.iterdir() if (p / "frames.csv").exists()):
        assert localize_cli.main([str(shared_datasets / name), "--method", "sphere"]) == 0
        text = capsys.readouterr().out
        assert "source 1:" in text and "error vs truth source 1" in text


def test_bad_input_is_reported(tmp_path, capsys):
    assert localize_cli.main([str(tmp_path / "missing"), "--method", "sphere"]) == 2
    assert "not a dataset directory" in capsys.readouterr().err
    assert localize_cli.main([str(tmp_path), "--method", "mle", "--set", "bogus=1"]) == 2
    assert "no setting" in capsys.readouterr().err


def test_a_repeated_frame_row_is_refused_naming_the_row(tmp_path, shared_datasets, capsys):
    """Issue 34: one row repeated 5 times was counted six times by localize; now the row is named, nothing fitted."""
    import shutil

    shutil.copy(shared_datasets / "lattice-clean" / "scenario.json", tmp_path)
    lines = (shared_datasets / "lattice-clean" / "frames.csv").read_text().splitlines()
    (tmp_path / "frames.csv").write_text("\n".join(lines[:11] + [lines[10]] * 5 + lines[11:]) + "\n")
    assert localize_cli.main([str(tmp_path), "--method", "sphere"]) == 2
    captured = capsys.readouterr()
    err = [ln for ln in captured.err.splitlines() if ln.strip()]
    assert len(err) == 1 and "frames.csv: row 12, column 't': repeats the previous row's time" in err[0], captured.err
    assert "Traceback" not in captured.err and captured.out == ""


def test_match_errors_pairs_each_truth_once():
    ds = lattice_flight(0)
    tr = ds.truth.sources[0]
    srcs = [{"x": tr.x + 3, "y": tr.y, "z": 0.0, "cps_at_1m": 1.0},
            {"x": tr.x + 0.1, "y": tr.y, "z": 0.0, "cps_at_1m": tr.cps_at_1m * 1.1}]
    e = truth_errors.match_errors(srcs, ds.truth)
    assert e[0]["estimate"] == 1 and e[0]["position_error_m"] == pytest.approx(0.1)
    assert e[0]["intensity_error_rel"] == pytest.approx(0.1)


def test_compare_writes_plot_and_identical_runs_have_zero_kl(tmp_path, capsys):
    a = lattice_flight(1)
    b = lattice_flight(1, cps_at_1m=1300.0)  # same flight, different source strength (a "simulator" off by 20 %)
    pa = write_dataset(tmp_path / "a", a.frames, a.scenario, a.truth)
    pb = write_dataset(tmp_path / "b", b.frames, b.scenario, b.truth)
    out = tmp_path / "cmp.png"
    assert compare_cli.main([str(pa), str(pa), "--out", str(out), "--n-particles", "3000", "--json"]) == 0
    same = json.loads(capsys.readouterr().out)
    assert same["final_kl"] == pytest.approx(0.0, abs=1e-9) and out.stat().st_size > 10_000
    assert compare_cli.main([str(pa), str(pb), "--out", str(out), "--n-particles", "3000", "--json"]) == 0
    diff = json.loads(capsys.readouterr().out)
    assert diff["median_kl"] > 0.01
    hist = compare_cli.replay(a, n_particles=2000)
    t, kl = compare_cli.kl_curve(hist, hist)
    assert np.allclose(kl, 0.0, atol=1e-9) and len(t) == len(hist)


@pytest.fixture(scope="module")
def simulated_lattice():
    from detector_fw_sim.scene import load_scene
    from detector_fw_sim.simulate import simulate_flight

    return simulate_flight(load_scene(), path="lattice", seed=3)


SETTINGS = {"pf": {"n_particles": 5000}, "multi-pf": {"n_particles": 1000},
            "gp": {"n_restarts": 1, "n_posterior_samples": 20}, "mle": {"n_starts": 1}, "sphere": {}}


@pytest.mark.parametrize("method", list(SETTINGS))
def test_every_method_on_a_simulated_flight(method, simulated_lattice):
    from estimator.localizers import make_localizer

    loc = make_localizer(method, **SETTINGS[method]).fit(simulated_lattice)
    err = truth_errors.match_errors(loc.sources_, simulated_lattice.truth)[0]
    assert err["position_error_m"] < (0.5 if method == "gp" else 0.15)
    assert abs(err["intensity_error_rel"]) < 0.15
    est = loc.to_estimate(t=1.0)
    assert est.method == method and len(est.covariance) == 16 * len(loc.sources_)


@pytest.mark.slow
def test_every_method_on_every_shared_dataset(shared_datasets):
    from estimator.localizers import make_localizer
    from radseek_io.truth import read_dataset_with_truth

    fast = {**SETTINGS, "mle": {"n_starts": 1, "pose_uncertainty": False, "compute_crlb": False}}
    for name in sorted(p.name for p in shared_datasets.iterdir() if (p / "frames.csv").exists()):
        ds = read_dataset_with_truth(shared_datasets / name)
        for method, st in fast.items():
            loc = make_localizer(method, **st).fit(ds)
            assert loc.sources_ and all(np.isfinite(list(s.values())).all() for s in loc.sources_), (name, method)
            assert np.isfinite(loc.covariance_).all(), (name, method)


def test_nan_pose_and_negative_counts_are_rejected_with_row_and_column(tmp_path, capsys):
    ds = lattice_flight(0)
    path = write_dataset(tmp_path / "bad", ds.frames, ds.scenario)
    lines = (path / "frames.csv").read_text().splitlines()
    header = lines[0].split(",")
    row = lines[5].split(",")
    row[header.index("x")] = "nan"
    lines[5] = ",".join(row)
    (path / "frames.csv").write_text("\n".join(lines) + "\n")
    assert localize_cli.main([str(path), "--method", "sphere"]) == 2
    err = capsys.readouterr().err
    assert "frames.csv" in err and "row 6" in err and "'x'" in err
    row[header.index("x")] = "1.0"
    row[header.index("c03")] = "-4"
    lines[5] = ",".join(row)
    (path / "frames.csv").write_text("\n".join(lines) + "\n")
    assert localize_cli.main([str(path), "--method", "sphere"]) == 2
    assert "'c03'" in capsys.readouterr().err


def test_compare_refuses_two_different_flights(shared_datasets, tmp_path, capsys):
    """Issue 35: compare took lattice-clean and two-sources without comment. It now names both fingerprints and
    what differs, exits 2 and writes nothing; --allow-different draws them with a warning."""
    a, b = shared_datasets / "lattice-clean", shared_datasets / "two-sources"
    out = tmp_path / "cmp.png"
    assert compare_cli.main([str(a), str(b), "--out", str(out), "--n-particles", "2000"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "not the same flight" in err and "9 dwells vs 14" in err
    da, db = (compare_cli.read_dataset(p) for p in (a, b))
    assert compare_cli.fingerprint(da) in err and compare_cli.fingerprint(db) in err
    assert not out.exists()
    assert compare_cli.main([str(a), str(b), "--out", str(out), "--n-particles", "2000", "--json",
                             "--allow-different"]) == 0
    cap = capsys.readouterr()
    summary = json.loads(cap.out)
    assert summary["same_flight"] is False and summary["differences"] and "warning" in cap.err and out.exists()


def test_same_flight_recorded_twice_has_one_fingerprint():
    """A flight and its 'simulated twin' (same poses, another source strength and counts) are one flight."""
    a, b = lattice_flight(1), lattice_flight(1, cps_at_1m=1300.0)
    assert compare_cli.flight_differences(a, b) == [] and compare_cli.fingerprint(a) == compare_cli.fingerprint(b)
    c = lattice_flight(2)  # another random source: the lattice is flown elsewhere
    assert compare_cli.flight_differences(a, c) and compare_cli.fingerprint(a) != compare_cli.fingerprint(c)


def test_compare_flags_a_collapsed_particle_cloud(shared_datasets, tmp_path, capsys):
    """lattice-wall through the wall-less filter (20000 particles, seed 0): the cloud's total variance falls to
    ~1e-6 m², decades below the Cramér-Rao floor of its counts. It is flagged with the time it happened, the
    warning says what it means, and the floor only falls as counts accrue. lattice-clean's cloud is not flagged."""
    ds = compare_cli.read_dataset(shared_datasets / "lattice-wall")
    pf = compare_cli.replay_filter(ds, n_particles=20000)
    floor = compare_cli.crlb_floor(ds, pf)
    assert np.all(np.diff(floor) <= 1e-12 * floor[:-1])  # information only accumulates
    tv = np.array([h["total_variance"] for h in pf.history_])
    assert tv[-1] < compare_cli.COLLAPSE_FRACTION * floor[-1]
    out = tmp_path / "cmp.png"
    p = str(shared_datasets / "lattice-wall")
    assert compare_cli.main([p, p, "--out", str(out), "--n-particles", "20000", "--json"]) == 0
    cap = capsys.readouterr()
    s = json.loads(cap.out)
    assert s["collapsed_at"][0] is not None and s["final_total_variance"][0] < 0.1 * s["floor_total_variance"][0]
    assert "collapsed" in cap.err and "not certainty" in cap.err
    clean = str(shared_datasets / "lattice-clean")
    assert compare_cli.main([clean, clean, "--out", str(out), "--n-particles", "20000", "--json"]) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["collapsed_at"] == [None, None] and s["final_total_variance"][0] >= s["floor_total_variance"][0]
