"""The issue-30 scoring of benchmarks/diagnose_evaluate.py on hand-made rows and reports (no diagnose runs)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from benchmarks import diagnose_evaluate as E


def _row(kind: str, named: list[str], truth: list[str], **kw) -> dict:
    return {"kind": kind, "name": kw.pop("name", f"{kind}-x"), "named": named, "truth": truth, "seconds": 1.0,
            "cpu_seconds": 1.0, **kw}


def test_named_nuclide_is_read_from_the_final_model_then_with_missing_then_candidates():
    assert E.named_nuclide({}) is None
    assert E.named_nuclide({"effect_params": {"second_source.nuclide": {"value": "Co-60", "error": None}}}) == "Co-60"
    assert E.named_nuclide({"effect_params": {}, "with_missing": {
        "effect_params": {"second_source.nuclide": {"value": "Ba-133"}}}}) == "Ba-133"
    j = {"candidates": [{"effect": "dead_time", "params": {"tau_s": 1e-6}}],
         "selection_steps": [{"candidates": [{"effect": "second_source", "params": {"nuclide": "Eu-152"}}]}]}
    assert E.named_nuclide(j) == "Eu-152"


def test_segment_and_wall_centre_distances_are_the_plane_geometry_ones():
    a, b = np.array([-1.0, 0.0]), np.array([1.0, 0.0])
    d = E.segment_distance(np.array([[0.0, 1.0], [3.0, 0.0], [-1.5, -2.0]]), a, b)
    assert d == pytest.approx([1.0, 2.0, math.hypot(0.5, 2.0)])
    true = [{"start": [0.0, 0.0], "end": [4.0, 0.0]}, {"start": [10.0, 10.0], "end": [10.0, 12.0]}]
    named = [{"start": [0.5, 0.3], "end": [1.5, 0.3]}, {"start": [9.0, 11.0], "end": [9.0, 11.0 + 1e-9]}]
    err = E.wall_errors(true, named)
    assert err[0] == {"segment": 0.3, "centre": round(math.hypot(1.0, 0.3), 3)}  # named centre (1, 0.3)
    assert err[1] == {"segment": 1.0, "centre": 1.0}  # named centre (9, 11): 1 m off the segment's middle
    assert E.wall_errors(true, []) == [] and E.wall_errors([], named) == []


def test_open_world_fields_default_before_the_report_has_them_and_read_them_after():
    before = E.open_world_fields({"missing": []}, {"second_source": {"x": 1, "y": 1, "cps_at_1m": 5}}, "Cs-137")
    assert before["unexplained"] is False and before["walls_named"] == 0 and before["nuclide_named"] is None
    assert before["nuclide_true"] == "Cs-137" and before["wall_centre_err_m"] == [] and before["hotspots"] == 0
    wall = {"start": [0.0, 0.0], "end": [2.0, 0.0], "thickness": 0.2, "height": 2.0}
    j = {"unexplained": True, "partial": ["pose_drift"], "residual_hotspots": [{"x": 1}, {"x": 2}],
         "unmapped_walls": [{**wall, "material": "unmapped", "mu_per_m": 2.0}],
         "effect_params": {"second_source.nuclide": {"value": "Co-60"}}}
    f = E.open_world_fields(j, {"unmapped_wall": {"walls": [wall], "mu_per_m": 2.0},
                                "second_source": {"nuclide": "Co-60"}}, "Cs-137")
    assert f["unexplained"] and f["partial"] == ["pose_drift"] and f["hotspots"] == 2 and f["walls_named"] == 1
    assert f["wall_centre_err_m"] == [{"segment": 0.0, "centre": 0.0}]
    assert f["nuclide_named"] == f["nuclide_true"] == "Co-60"


def _wall_row(mt: float, named: list[str], errs: list[dict], n_true: int, walls_named: int, **kw) -> dict:
    tp = {"unmapped_wall": {"walls": [{}] * n_true}}
    return _row("walls", named, ["unmapped_wall"], strength=mt, wall_centre_err_m=errs, truth_params=tp,
                walls_named=walls_named, **kw)


def test_walls_table_rates_per_mu_t_and_the_target():
    rows = [
        _wall_row(0.3, ["unmapped_wall"], [{"segment": 0.2, "centre": 0.9, "shaded_centre": 0.3},
                                           {"segment": 0.7, "centre": 0.4}], 2, 1),
        _wall_row(0.3, [], [], 1, 0),
        _wall_row(1.0, ["unmapped_wall", "dead_time"], [{"segment": 0.1, "centre": 0.1}], 1, 1),
        _row("null", [], []),  # other kinds are left out
    ]
    text, s = E.walls_table(rows)
    # the shaded part's centre stands in for the centre where a row has none
    assert s[0.3] == {"n": 2, "detected": 0.5, "located_segment": 1 / 3, "located_centre": 1 / 3,
                      "located_shaded": 2 / 3, "located_seen": 0.0, "every_located": 0.0, "flights_located": 0.5}
    assert s[1.0] == {"n": 1, "detected": 1.0, "located_segment": 1.0, "located_centre": 1.0,
                      "located_shaded": 1.0, "located_seen": 0.0, "every_located": 1.0, "flights_located": 1.0}
    assert "| 1 | 1 | 1/1 (100%) | 1/1 / 1/1 / 1/1 / 0/1 | 1/1 | 1/1 | 1 (1) | 1 | 0 |" in text  # dead_time: another
    assert "NOT met" in text
    good = [_wall_row(mt, ["unmapped_wall"], [{"segment": 0.1, "centre": 0.4}], 1, 1) for mt in (0.3, 0.5, 1.0)]
    text, _ = E.walls_table(good + [_wall_row(0.1, [], [], 1, 0)])  # weak walls do not count for the target
    assert "lowest located (centre) 100%, (shaded part's centre) 100%, (that centre by a named wall's seen part) 0%: " \
        "met per true" in text
    # one of two true walls located on every flight: met per flight, not per wall
    half = [_wall_row(mt, ["unmapped_wall"], [{"segment": 0.1, "centre": 0.4}, {"segment": 0.9, "centre": 1.2}], 2, 1)
            for mt in (0.3, 0.5, 1.0)]
    text, _ = E.walls_table(half)
    assert "(centre) 50%" in text and "NOT met per true wall" in text and "located 100%: met per flight" in text
    far = [_wall_row(mt, ["unmapped_wall"], [{"segment": 0.1, "centre": 0.6}], 1, 1) for mt in (0.3, 0.5, 1.0)]
    assert "NOT met" in E.walls_table(far)[0]  # the target is the centre, not the segment


def test_a_slab_scaled_about_the_source_casts_the_same_shadow_until_a_frame_changes_side():
    src = np.array([0.0, 0.0])
    wall = {"start": [2.0, -1.0], "end": [2.0, 1.0]}  # 2 m east of the source, centre at r = 2
    # frames due east at 1 m (lit, before the slab) and at 4 m (shaded): s = 2 and 0.5
    frames = np.array([[1.0, 0.0], [4.0, 0.0], [0.0, 3.0]])  # the last is outside the sector
    lo, hi = E.placement_range(src, wall, frames)
    # shaded for k <= 1/0.5 = 2, lit for k > 1/2: the centre may move from -1 m (k = 1/2) to +2 m (k = 2)
    assert (lo, hi) == (-1.0, 2.0)
    # with no frame between the source and the slab it can slide all the way to the source
    assert E.placement_range(src, wall, frames[1:])[0] == -2.0
    part = E.shaded_part(src, wall, np.array([[4.0, 0.0], [4.0, 1.0], [4.0, -4.0]]))
    # lines of sight to (4, 0) and (4, 1) cross x = 2 at y = 0 and 0.5; (4, -4) passes below the slab's end
    assert part == {"start": [2.0, 0.0], "end": [2.0, 0.5]}
    assert E.shaded_part(src, wall, np.array([[1.0, 0.0]])) is None  # in the sector, but before the slab
    errs = E.wall_errors([{**wall, "shaded": part}], [{"start": [2.0, 0.2], "end": [2.0, 0.3]}])
    assert errs == [{"segment": 0.0, "centre": 0.25, "shaded_centre": 0.0}]
    # a named wall twice as long as its seen part: its centre is 0.5 m off, its seen part's centre on the true one's
    named = {"start": [2.1, -0.25], "end": [2.1, 1.75], "seen_part": {"start": [2.1, 0.0], "end": [2.1, 0.5]}}
    errs = E.wall_errors([{**wall, "shaded": part}], [named])
    assert errs == [{"segment": 0.1, "centre": round(math.hypot(0.1, 0.75), 3),
                     "shaded_centre": round(math.hypot(0.1, 0.5), 3), "seen_shaded": 0.1}]


def test_the_seen_part_of_a_slab_is_where_the_lines_of_sight_cross_it():
    """``shadow.seen_part`` (diagnose's ``unmapped_walls[].seen_part``): a 4 m slab 2 m east of the source, frames
    4 m east at y = -0.5 and 0.5 and one between the source and the slab: the lines of sight cross it over its
    middle half metre, the part the counts locate."""
    from estimator.diagnose.shadow import seen_part

    frames = np.array([[4.0, -0.5], [4.0, 0.5], [1.0, 0.0]])
    assert seen_part(np.zeros(2), [2.0, -2.0], [2.0, 2.0], frames) == {"start": [2.0, -0.25], "end": [2.0, 0.25]}
    assert seen_part(np.zeros(2), [2.0, 1.0], [2.0, 2.0], frames) is None  # above every line of sight


def test_nuclides_table_right_rate_per_true_nuclide():
    rows = [_row("nuclides", ["second_source"], ["second_source"], nuclide_true="Co-60", nuclide_named="Co-60"),
            _row("nuclides", ["second_source"], ["second_source"], nuclide_true="Co-60", nuclide_named="Cs-137"),
            _row("nuclides", [], ["second_source"], nuclide_true="Co-60", nuclide_named=None),
            _row("nuclides", ["second_source"], ["second_source"], nuclide_true="Ba-133", nuclide_named="Ba-133")]
    text, s = E.nuclides_table(rows)
    assert s["Co-60"] == {"n": 3, "detected": 2 / 3, "right": 1 / 3, "right_of_named": 0.5, "right_of_shown": None}
    assert s["Ba-133"]["right"] == 1.0 and "lowest 33%: NOT met" in text
    assert "| Co-60 | 3 | 2/3 | 1/2 | 1/3 (33%) | Co-60, Cs-137 | -/1 | 1/2 (50%) |" in text


def test_nuclides_table_counts_a_missed_second_source_the_counts_could_not_show_apart():
    """A flight where diagnose did not name the second source, and the true second source fits the counts no better
    than the baseline (AIC gap below TOLD_APART_AIC), is left out of "right of those the counts show"; one the
    counts tell apart stays in it as a miss."""
    hidden = {"aic_gap": 3.0, "told_apart": False}
    shown = {"aic_gap": 25.0, "told_apart": True}
    rows = [_row("nuclides", ["second_source"], ["second_source"], nuclide_true="Eu-152", nuclide_named="Eu-152"),
            _row("nuclides", [], ["second_source"], nuclide_true="Eu-152", nuclide_named=None, truth_model=hidden),
            _row("nuclides", ["second_source"], ["second_source"], nuclide_true="Ba-133", nuclide_named="Ba-133"),
            _row("nuclides", [], ["second_source"], nuclide_true="Ba-133", nuclide_named=None, truth_model=shown)]
    text, s = E.nuclides_table(rows)
    assert s["Eu-152"]["right"] == 0.5 and s["Eu-152"]["right_of_shown"] == 1.0
    assert s["Ba-133"]["right_of_shown"] == 0.5
    assert "| Eu-152 | 2 | 1/2 | 1/1 | 1/2 (50%) | Eu-152 | 0/1 (+3) | 1/1 (100%) |" in text
    assert "lowest 50%" in text.splitlines()[-1]


def test_offlist_table_counts_unexplained_and_any_named_effect_as_wrong():
    carried = {"effect": "moving_source", "variant": "source_carried"}
    rows = [_row("offlist", [], ["moving_source"], unexplained=True, **carried),
            _row("offlist", ["pose_drift"], ["moving_source"], unexplained=True, **carried),
            _row("offlist", [], ["background_drift"], effect="background_drift", unexplained=False, hotspots=2)]
    text, s = E.offlist_table(rows)
    assert s["source_carried"] == {"n": 2, "unexplained": 1.0, "wrong": 1, "told_apart": None}
    assert s["background_drift"] == {"n": 1, "unexplained": 0.0, "wrong": 0, "told_apart": None}
    assert "67%, 1 wrong: NOT met" in text and "(pose_drift)" in text
    ok = [_row("offlist", [], ["moving_source"], unexplained=True, **carried)] * 10
    assert "100%, 0 wrong: met" in E.offlist_table(ok)[0]


def test_offlist_table_counts_the_flights_whose_truth_the_counts_tell_apart():
    """A carried source whose true model beats the named one by AIC >= 10 is told apart; only those could be
    called unexplained from the counts, and the table says how many of them were."""
    carried = {"effect": "moving_source", "variant": "source_carried"}

    def gap(aic, unexplained):
        return _row("offlist", [] if unexplained else ["pose_drift"], ["moving_source"], unexplained=unexplained,
                    truth_model={"aic_gap": aic, "told_apart": aic >= E.TOLD_APART_AIC}, **carried)

    text, s = E.offlist_table([gap(-3.0, False), gap(4.0, False), gap(40.0, True), gap(12.0, False)])
    assert s["source_carried"]["told_apart"] == 2
    assert "| 2/4 (AIC gap -3 to +40) | 1/2 |" in text


def test_a_constant_velocity_source_is_scored_as_its_pose_drift_equivalent_not_as_off_list():
    truth = {"moving_source": {"vx": 0.010, "vy": -0.020}}

    def row(named, vx, vy, sd=0.001):
        return _row("offlist", named, ["moving_source"], effect="moving_source", variant="moving_source",
                    unexplained=False, truth_params=truth,
                    params={"pose_drift.vx": [vx, sd], "pose_drift.vy": [vy, sd]} if named else {})

    rows = [row(["pose_drift"], 0.011, -0.021),  # within 3 sd + 2 mm/s: the equivalent, right
            row(["pose_drift"], -0.010, 0.020),  # the opposite sign: not the same counts
            row(["pose_drift", "dead_time"], 0.010, -0.020),  # another effect beside it: not the equivalent
            row([], 0, 0)]
    assert [E.equivalent_named(r) for r in rows] == [True, False, False, False]
    text, s = E.offlist_table(rows)
    assert s == {"moving_source (= pose_drift)": {"n": 4, "equivalent_named": 1}}
    assert "Target" not in text and "in 1/4" in text


def test_conull_false_alarms_allow_the_true_over_dispersion_and_count_unexplained():
    assert not E.false_alarm(_row("conull", ["over_dispersion"], ["over_dispersion"]))
    assert E.false_alarm(_row("conull", ["over_dispersion"], []))
    assert E.false_alarm(_row("conull", [], [], unexplained=True))
    rows = [_row("conull", [], [], primary_nuclide="Co-60") for _ in range(49)]
    rows += [_row("conull", ["gain_drift"], [], primary_nuclide="Co-60", name="bad")]
    rows += [_row("conull", [], [], primary_nuclide="Cs-137") for _ in range(50)]
    text, s = E.conull_table(rows)
    assert s["all"] == {"n": 100, "false_alarms": 1, "rate": 0.01}
    assert s["Co-60"] == {"n": 50, "false_alarms": 1} and s["Cs-137"] == {"n": 50, "false_alarms": 0}
    assert "1/100 (1.0%; target <= 2%): met (bad)" in text
    rows += [_row("conull", [], [], primary_nuclide="Cs-137", unexplained=True)] * 2
    assert "NOT met" in E.conull_table(rows)[0]


def test_report_has_the_new_sections_and_jobs_build_them():
    rows = [_wall_row(0.5, ["unmapped_wall"], [{"segment": 0.1, "centre": 0.1}], 1, 1),
            _row("nuclides", ["second_source"], ["second_source"], nuclide_true="Eu-152", nuclide_named="Eu-152"),
            _row("conull", [], [], primary_nuclide="Co-60"),
            _row("offlist", [], ["background_drift"], effect="background_drift", unexplained=True)]
    text, s = E.report(rows)
    for title in ("Unmapped walls", "Second sources of other nuclides", "Co-60 and Cs-137 primaries",
                  "Off-list physics"):
        assert title in text
    assert set(s) >= {"walls", "nuclides", "conull", "offlist"}
    js = E.jobs(["walls", "nuclides", "conull", "offlist"], 3, 0, 20)
    walls = [j for j in js if j["kind"] == "walls"]
    assert len(walls) == 3 * len(E.WALL_MU_T)
    for j in walls:
        uw = j["spec"]["effects"]["unmapped_wall"]
        for w in uw.get("walls", []):
            assert uw["mu_per_m"] * w["thickness"] == pytest.approx(j["strength"])
    assert {len(j["spec"]["effects"]["unmapped_wall"].get("walls", [])) for j in walls} >= {1, 2, 3}
    assert any(j["spec"].get("unmap_walls") for j in walls)
    nuc = [j for j in js if j["kind"] == "nuclides"]
    assert {j["spec"]["effects"]["second_source"]["nuclide"] for j in nuc} == set(E.NUCLIDES)
    co = [j for j in js if j["kind"] == "conull"]
    assert len(co) == 20 and sum(j["spec"]["nuclide"] == "Co-60" for j in co) == 10
    assert all(set(j["spec"]["effects"]) <= {"over_dispersion"} for j in co)
    assert {j["spec"]["pose_error"] for j in co} == {"random_walk", "independent"}
    off = [j for j in js if j["kind"] == "offlist"]
    assert {e for j in off for e in j["spec"]["effects"]} == {"moving_source", "background_drift"}
    assert len({j["name"] for j in js}) == len(js)


def test_open_world_curves_rate_per_strength():
    rows = [_wall_row(0.1, [], [], 1, 0), _wall_row(0.1, ["unmapped_wall"], [], 1, 1),
            _wall_row(0.5, ["unmapped_wall"], [], 1, 1),
            _row("nuclides", ["second_source"], ["second_source"], strength=300.0, nuclide_true="Co-60",
                 nuclide_named="Cs-137"),
            _row("nuclides", ["second_source"], ["second_source"], strength=1300.0, nuclide_true="Co-60",
                 nuclide_named="Co-60")]
    c = E.open_world_curves(rows)
    assert c["unmapped_wall"] == {"strengths": [0.1, 0.5], "rates": [0.5, 1.0], "p50": 0.1}
    assert c["second_source Co-60"]["rates"] == [0.0, 1.0]
    assert c["second_source Co-60"]["p50"] == pytest.approx(math.sqrt(300.0 * 1300.0))  # log-linear half way


@pytest.mark.parametrize("cps, told", [(1300.0, True), (3.0, False)])
def test_the_truth_models_gap_for_a_second_source_diagnose_did_not_name(cps, told):
    """A second source 1300 cps at 1 m in a lawnmower's corner (forward2) fits the counts far better than the
    baseline, at its true place; one of 3 cps (a tenth of the background at 1 m) does not show."""
    from benchmarks.forward2 import FlightSpec, simulate
    from estimator.diagnose.backend import split_transit_legs
    from estimator.mle import fit
    from estimator.model import MeasurementModel

    second = {"x": 1.5, "y": 1.5, "z": 0.0, "cps_at_1m": cps, "nuclide": "Cs-137"}
    ds = simulate(FlightSpec(geometry="lawnmower", effects={"second_source": second}), seed=3)
    baseline = fit(MeasurementModel(ds.scenario), split_transit_legs(ds.frames), n_starts=2)
    gap = E.truth_model_gap(ds, baseline)
    assert gap["effect"] == "second_source" and gap["k_truth"] == gap["k_named"] + 3
    assert gap["told_apart"] is told
    if told:
        for k in ("x", "y"):
            assert abs(gap["fitted"][f"second_source.{k}"] - second[k]) <= 3 * gap["fitted_err"][f"second_source.{k}"]


def test_the_truth_models_gap_tells_a_strong_background_ramp_from_the_baseline():
    """A background ramping at 60 %/min on a 100 cps background (forward2): the truth model (the ramp free) fits the
    counts far better than the baseline diagnose would keep, and its fitted ramp is the true one."""
    from benchmarks.forward2 import FlightSpec, simulate
    from estimator.diagnose.backend import split_transit_legs
    from estimator.mle import fit
    from estimator.model import MeasurementModel

    ds = simulate(FlightSpec(geometry="lawnmower", effects={"background_drift": {"percent_per_min": 60.0}},
                             background_cps=100.0), seed=5)
    baseline = fit(MeasurementModel(ds.scenario), split_transit_legs(ds.frames), n_starts=2)
    gap = E.truth_model_gap(ds, baseline)
    assert gap["effect"] == "background_drift" and gap["k_truth"] == gap["k_named"] + 1
    assert gap["told_apart"]
    key = "background_drift.percent_per_min"
    assert abs(gap["fitted"][key] - 60.0) <= 3 * gap["fitted_err"][key]
