"""Scenes: bundled files load, bad input names the field and value, truth/scenario follow the dataset spec."""

from __future__ import annotations

import json

import numpy as np
import pytest

from detector_fw_sim.ladder import REFERENCE_EDGES_KEV, ComparatorLadder, drifted_edges, gain_factor
from detector_fw_sim.scene import SceneError, bundled_scenes, load_scene
from radseek.dataset import EFFECTS


def test_every_bundled_scene_loads():
    names = bundled_scenes()
    assert {"default", "lattice-wall", "outdoor", "two-source", "co60"} <= set(names)
    for name in names:
        scene = load_scene(name)
        assert scene.truth().sources and scene.scenario().channel_edges_keV.shape == (33,)


def test_default_scene_is_one_cs137_source_without_effects():
    scene = load_scene()
    assert [s.nuclide for s in scene.sources] == ["Cs-137"]
    assert scene.enabled_effects() == []
    assert scene.truth().effects == {}
    assert np.allclose(scene.channel_edges_keV, REFERENCE_EDGES_KEV)


def test_scenario_hides_the_sources_and_truth_uses_spec_names():
    scene = load_scene("two-source")
    scenario = scene.scenario().to_dict()
    text = json.dumps(scenario)
    assert "sources" not in scenario and "second_source" not in text and "2200" not in text
    truth = scene.truth()
    assert truth.sources[0].cps_at_1m == 2200.0
    assert truth.effects["second_source"] == {"x": 8.1, "y": 3.0, "z": 0.0, "cps_at_1m": 1300.0}
    assert len(truth.all_sources()) == 2


@pytest.mark.parametrize("name", list(EFFECTS))
def test_with_effect_switches_each_vocabulary_effect_on(name):
    base = load_scene("lattice-wall") if name == "wall_attenuation" else load_scene()
    scene = base.with_effect(name)
    effects = scene.truth().effects
    assert name in effects and set(EFFECTS[name]) <= set(effects[name])
    assert all(np.isfinite(v) for v in effects[name].values())
    assert base.truth().effects.get(name) is None or name == "wall_attenuation"
    assert scene.without_effects().truth().effects == {}


def test_with_effect_sets_parameters_and_rejects_bad_ones():
    scene = load_scene().with_effect("gain_drift", percent_per_min=2.0)
    assert scene.truth().effects["gain_drift"] == {"percent_per_min": 2.0}
    with pytest.raises(SceneError, match=r"effects\.anisotropy\.fraction.*got 2"):
        load_scene().with_effect("anisotropy", fraction=2)
    with pytest.raises(SceneError, match="unknown effect 'bogus'"):
        load_scene().with_effect("bogus")
    with pytest.raises(SceneError, match=r"effects\.dead_time\.tau"):
        load_scene().with_effect("dead_time", tau=1e-5)


def write(tmp_path, text: str, suffix: str = ".toml"):
    p = tmp_path / f"scene{suffix}"
    p.write_text(text)
    return p


SOURCE = '[[sources]]\nnuclide = "Cs-137"\nposition = [1.0, 2.0, 0.0]\n'


@pytest.mark.parametrize(
    ("body", "pattern"),
    [
        (SOURCE + "cps_at_1m = -5\n", r"sources\[0\]\.cps_at_1m.*greater than 0.*got -5"),
        (SOURCE, r"sources\[0\].*exactly one of cps_at_1m or activity_MBq"),
        (SOURCE + "cps_at_1m = 1\nactivity_MBq = 2\n", r"exactly one of cps_at_1m or activity_MBq"),
        ('[[sources]]\nnuclide = "Xx-999"\nposition = [0, 0, 0]\ncps_at_1m = 5\n', r"sources\[0\]\.nuclide.*Xx-999"),
        (SOURCE + "cps_at_1m = 5\ncolour = 'red'\n", r"sources\[0\]\.colour.*not permitted.*red"),
        (SOURCE.replace("[1.0, 2.0, 0.0]", "[1.0, 2.0]") + "cps_at_1m = 5\n", r"sources\[0\]\.position"),
        (SOURCE + 'cps_at_1m = 5\n[[walls]]\nstart = [0, 0]\nend = [1, 0]\nthickness = 0.2\nmaterial = "cheese"\n',
         r"walls\[0\]\.material.*unknown material 'cheese'"),
        (SOURCE + "cps_at_1m = 5\n[detector]\nchannel_edges_keV = [1, 2, 3]\n", r"detector\.channel_edges_keV.*33"),
        (SOURCE + "cps_at_1m = 5\n[bounds]\nmin = [0, 0, 0]\nmax = [-1, 5, 1]\n", r"bounds.*max must be >= min"),
        (SOURCE + "cps_at_1m = 5\n[effects.dead_time]\nenabled = true\ntau_s = 'fast'\n",
         r"effects\.dead_time\.tau_s.*fast"),
        ("name = 'x'\n", r"field 'sources'.*required"),
        (SOURCE + "cps_at_1m = 5\n[background\n", r"not valid TOML"),
    ],
)
def test_scene_errors_name_the_field_and_value(tmp_path, body, pattern):
    p = write(tmp_path, body)
    with pytest.raises(SceneError, match=pattern) as info:
        load_scene(p)
    assert str(p) in str(info.value)


def test_json_scenes_and_missing_files(tmp_path):
    p = write(tmp_path, json.dumps({"sources": [{"position": [1, 2, 0], "activity_MBq": 100.0}]}), ".json")
    scene = load_scene(p)
    assert scene.truth().sources[0].cps_at_1m > 0  # converted from MBq with the crystal's efficiency
    bad = write(tmp_path, "{not json", ".json")
    with pytest.raises(SceneError, match="not valid JSON"):
        load_scene(bad)
    with pytest.raises(SceneError, match="not found.*bundled scenes"):
        load_scene(tmp_path / "nope.toml")


def test_activity_conversion_is_written_to_truth():
    co = load_scene("co60")
    cps = co.truth().sources[0].cps_at_1m
    assert cps == pytest.approx(co.source_cps_at_1m(0), rel=1e-3)
    # two photons per decay: more counts per MBq than Cs-137's 0.85
    data = co.model_dump()
    data["sources"][0]["nuclide"] = "Cs-137"
    from detector_fw_sim.scene import validate_scene

    cs = validate_scene(data)
    assert cps > 1.5 * cs.source_cps_at_1m(0)


def test_comparator_ladder_round_trips_and_drifts():
    ladder = ComparatorLadder.from_edges(np.array(REFERENCE_EDGES_KEV))
    assert ladder.edges_keV() == pytest.approx(np.array(REFERENCE_EDGES_KEV))
    v = ladder.thresholds_V()
    assert v.shape == (32,) and np.all(np.diff(v) > 0) and ladder.tap_voltages_V()[-1] == pytest.approx(3.3)
    assert gain_factor(60.0, 2.0) == pytest.approx(1.02)
    e = drifted_edges(ladder.edges_keV(), np.array([0.0, 600.0]), 2.0)
    assert e[1] == pytest.approx(e[0] / 1.2)
    with pytest.raises(ValueError, match="33"):
        ComparatorLadder((1.0,) * 10)


def test_a_scene_flown_in_air_tells_the_operator_the_librarys_coefficient():
    """outdoor switches air_attenuation on: its scenario carries NIST XCOM dry air at 662 keV (0.0093 /m
    to two figures), whatever the scene's own override; scenes without air carry none."""
    outdoor = load_scene("outdoor")
    assert outdoor.scenario().air_mu_per_m == pytest.approx(0.0093, abs=5e-5)
    assert outdoor.with_effect("air_attenuation", mu_per_m=0.02).scenario().air_mu_per_m == \
        outdoor.scenario().air_mu_per_m
    assert load_scene("default").scenario().air_mu_per_m == 0.0
