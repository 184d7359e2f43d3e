"""radseek diagnose on data with a hidden effect: the shared reference datasets and emulated flights.

Each full diagnose fits ~15 models with pose uncertainty, so only a few datasets run here (the closing
table of all shared and emulated datasets is produced by ``python benchmarks/diagnose_evaluate.py``).
"""

from __future__ import annotations

import io
import json
from contextlib import redirect_stdout
from pathlib import Path

import pytest

from estimator.diagnose.runner import diagnose
from radseek_cli.diagnose_cli import main
from radseek_io.truth import read_dataset_with_truth
from reporting.truth_errors import score_diagnosis
from tests.support.once_per_run import once_per_run


def _run_cli(argv: list[str]) -> tuple[int, str]:
    buf = io.StringIO()
    with redirect_stdout(buf):
        code = main(argv)
    return code, buf.getvalue()


def _anisotropy_run(shared_datasets, tmp_path_factory) -> tuple[int, str, Path]:
    """``radseek diagnose spin-anisotropy --json`` once per test run: (exit code, stdout, its output folder)."""
    def run(folder: Path) -> tuple[int, str, Path]:
        code, out = _run_cli([str(shared_datasets / "spin-anisotropy"), "--json", "--quiet", "--out", str(folder),
                              "--starts", "4"])
        return code, out, folder

    return once_per_run(tmp_path_factory, "diagnose-spin-anisotropy", run)


@pytest.mark.io
def test_cli_json_names_the_anisotropy_and_adding_it_brings_the_fit_home(shared_datasets, tmp_path_factory):
    code, out, folder = _anisotropy_run(shared_datasets, tmp_path_factory)
    assert code == 0
    rep = json.loads(out)
    for key in ("model", "deviance_per_dof", "p_value", "sources", "candidates", "missing"):
        assert key in rep
    assert rep["model"] == []
    assert rep["missing"] == ["anisotropy"]
    top = rep["candidates"][0]
    assert top["effect"] == "anisotropy" and top["delta_aic"] < -20 and top["significant"]
    assert top["explains"] == "bearing"
    assert 0.3 < top["params"]["anisotropy.fraction"] < 0.7  # truth 0.5
    after = rep["with_missing"]
    assert abs(after["deviance_per_dof"] - after["deviance_per_dof_expected"]) < 4 * after["deviance_per_dof_sd"]
    assert after["deviance_per_dof"] < rep["deviance_per_dof"]
    assert {"x", "y", "z", "cps_at_1m"} <= set(rep["sources"][0])
    assert all(p.endswith(".png") for p in rep["plots"]) and (folder / "residual_map.png").exists()


@pytest.mark.io
def test_cli_add_after_a_run_reuses_its_fits_and_shows_before_and_after(shared_datasets, tmp_path_factory, capsys):
    """The tutorial's step: the effect a run named, added in that run's folder (its fits.pkl reused: the baseline
    and the selection are not searched again; a fresh `--add` on lattice-clean cost 16 s of CPU here)."""
    *_, folder = _anisotropy_run(shared_datasets, tmp_path_factory)
    capsys.readouterr()
    code, out = _run_cli([str(shared_datasets / "spin-anisotropy"), "--add", "anisotropy", "--out", str(folder),
                          "--starts", "4", "--jobs", "1"])
    assert code == 0
    assert f"reusing the fits and selections saved in {folder / 'fits.pkl'}" in capsys.readouterr().err
    assert "5. Added: baseline (sources + constant background) + anisotropy" in out
    assert "deviance/dof" in out and "->" in out and "anisotropy.fraction" in out
    assert "electronics and mounting behind the crystal" in out  # the physics sentence
    assert "6. Is anything still missing?" in out and "is adequate" in out
    assert (folder / "before_after.png").exists()


def test_bad_input_exits_2(tmp_path, capsys):
    assert main([str(tmp_path / "nope")]) == 2
    assert main([str(tmp_path), "--alpha", "2"]) == 2


def _sim(effect: str | None, path: str = "lattice", seed: int = 5, **params):
    from detector_fw_sim.scene import load_scene
    from detector_fw_sim.simulate import simulate_flight

    scene = load_scene().without_effects()
    if effect:
        scene = scene.with_effect(effect, **params)
    return simulate_flight(scene, path=path, seed=seed)


@pytest.mark.slow
def test_null_emulated_flight_is_called_adequate():
    d = diagnose(_sim(None, seed=21), quiet=True, n_starts=4)
    assert d.selection.missing == []
    assert d.after is None


@pytest.mark.parametrize(
    ("effect", "params", "feature"),
    [
        ("background_gradient", {"gx": 3.0, "gy": -2.0}, "position"),
        ("pose_drift", {"vx": 0.003, "vy": -0.002}, None),
    ],
)
@pytest.mark.slow
def test_emulated_effect_is_named(effect, params, feature):
    ds = _sim(effect, path="lawnmower" if effect == "background_gradient" else "lattice", **params)
    d = diagnose(ds, quiet=True, n_starts=4)
    assert d.selection.missing[:1] == [effect]
    top = d.selection.first[0]
    assert top.effect == effect and top.significant
    if feature:
        assert top.explains == feature
    assert d.after is not None
    assert abs(d.after.gof.deviance_per_dof - d.after.gof.expected_per_dof) < 4 * d.after.gof.sd_per_dof


def test_clean_shared_dataset_reads_without_truth_leak(shared_datasets):
    # the fit never reads truth: the same answer with the truth removed
    ds = read_dataset_with_truth(shared_datasets / "lattice-clean")
    no_truth = type(ds)(frames=ds.frames, scenario=ds.scenario, truth=None, path=ds.path)
    from estimator.diagnose.backend import CountFitter

    a = CountFitter(ds.scenario, ds.frames, n_starts=2, quiet=True).fit(())
    b = CountFitter(no_truth.scenario, no_truth.frames, n_starts=2, quiet=True).fit(())
    assert a.values == b.values


@pytest.mark.slow
def test_two_missing_effects_are_both_found_one_after_the_other():
    from detector_fw_sim.scene import load_scene
    from detector_fw_sim.simulate import simulate_flight

    scene = (load_scene().without_effects().with_effect("anisotropy", fraction=0.5, half_angle_deg=30.0)
             .with_effect("background_gradient", gx=3.0, gy=-2.0))
    ds = simulate_flight(scene, path="lawnmower", seed=5)
    d = score_diagnosis(diagnose(ds, quiet=True, n_starts=4), ds.truth)
    assert d.selection.missing == ["anisotropy", "background_gradient"]
    assert d.selection.steps[1].effects == ("anisotropy",)  # the second is tested given the first
    assert d.after is not None and d.after.effects == ("anisotropy", "background_gradient")
    assert d.after.source_error_m < d.current.source_error_m
    assert abs(d.after.gof.deviance_per_dof - d.after.gof.expected_per_dof) < 4 * d.after.gof.sd_per_dof
