"""The backward check of diagnose's selection (``estimator.diagnose.runner._backward``) on a flight from the
independent generator (benchmarks/forward2): an effect the forward selection named that the model does not need
is dropped, the one the world has is kept, and the drop fits give the same answer run one by one or as a batch
in two processes (``--jobs 2``)."""

from __future__ import annotations

import pytest

from benchmarks.forward2 import FlightSpec, simulate
from estimator.diagnose.backend import CountFitter
from estimator.diagnose.runner import _backward
from estimator.diagnose.selection import Candidate, Selection, Step


@pytest.fixture(scope="module")
def flight():
    # a background gradient of 3.6 cps/m over a 30 cps background: the world has it, and no dead time
    return simulate(FlightSpec(geometry="lattice", effects={"background_gradient": {"gx": 3.0, "gy": -2.0}}), seed=3)


def _selection(fitter: CountFitter, named: list[str]) -> Selection:
    """A forward selection that named ``named`` in that order, each step's chosen candidate carrying its fit."""
    steps, model = [], ()
    for e in named:
        model = (*model, e)
        fit = fitter.fit(model)
        steps.append(Step(model[:-1], [Candidate(e, 50.0, 1, -48.0, -10.0, "chi2_1", {}, {}, True, 1e-3, fit=fit)],
                          e))
    return Selection(steps, list(named), 0.01)


def _run(flight, jobs: int):
    fitter = CountFitter(flight.scenario, flight.frames, n_starts=2, quiet=True, jobs=jobs)
    return _backward(fitter, _selection(fitter, ["dead_time", "background_gradient"]), (), 0.01, True)


def test_a_needless_effect_is_dropped_and_the_worlds_effect_kept(flight):
    dropped, reduced, records = _run(flight, 1)
    assert dropped == ["dead_time"]
    assert [r["effect"] for r in records] == ["dead_time"] and records[0]["p_value"] > 0.01 / 2
    assert reduced.model.effects == ("background_gradient",)
    assert reduced.values["background_gradient.gx"] > 0 > reduced.values["background_gradient.gy"]


@pytest.mark.io  # forks its worker processes
def test_the_drop_fits_give_the_same_answer_in_two_processes(flight):
    one, two = _run(flight, 1), _run(flight, 2)
    assert one[0] == two[0] == ["dead_time"]
    # the same fits from the same starts, whether in this process or in a forked worker
    assert one[1].nll == pytest.approx(two[1].nll, abs=1e-9)


def test_nothing_is_dropped_when_every_named_effect_is_needed(flight):
    fitter = CountFitter(flight.scenario, flight.frames, n_starts=2, quiet=True)
    sel = _selection(fitter, ["background_gradient"])
    assert _backward(fitter, sel, (), 0.01, True) == ([], None, [])  # one named effect: nothing to check


def test_a_variance_effect_named_between_count_effects_does_not_stop_the_check(flight):
    """over_dispersion's candidate carries a DispersionFit, not a count fit: the check starts from the count effects'
    fits alone (it raised AttributeError on a three-slab flight whose step 4 named over_dispersion)."""
    from estimator.diagnose.dispersion import fit_dispersion

    fitter = CountFitter(flight.scenario, flight.frames, n_starts=2, quiet=True)
    sel = _selection(fitter, ["dead_time", "background_gradient"])
    disp = fit_dispersion(fitter.fit_frames, sel.steps[-1].candidates[0].fit.expected)
    sel.steps.append(Step(("dead_time", "background_gradient"),
                          [Candidate("over_dispersion", 20.0, 1, -18.0, -5.0, "chi2_1", {}, {}, True, 1e-3, fit=disp)],
                          "over_dispersion"))
    sel.missing.append("over_dispersion")
    dropped, reduced, _ = _backward(fitter, sel, (), 0.01, True)
    assert dropped == ["dead_time"] and reduced.model.effects == ("background_gradient",)


def test_a_drop_fit_below_the_full_fit_is_dropped_and_says_the_full_fit_stopped_short(flight, monkeypatch, capsys):
    """The model with every effect nests each drop's, so a drop fit below it shows the full fit stopped in a worse
    minimum (a three-slab flight: the fit without its second source 44.1 lower). Injected here: every full fit
    returns 5 above where it was found, the one fitted again from the drop's basin too. The refit is said; the drop
    is still below it, so its LR is 0, the effect goes, and the message and the record say by how much the full fit
    fell short; with the true full fit the record says 0."""
    fitter = CountFitter(flight.scenario, flight.frames, n_starts=2, quiet=True)
    sel = _selection(fitter, ["dead_time", "background_gradient"])
    dropped, _, honest = _backward(fitter, sel, (), 0.01, True)
    fit = fitter.fit
    full_key = ("dead_time", "background_gradient")

    calls = []

    def stopped_short(effects, *a, **k):
        calls.append(tuple(effects)) if "init" in k else None
        res = fit(effects, *a, **k)
        return replace(res, nll=res.nll + 5.0) if tuple(effects) == full_key and "init" in k else res

    from dataclasses import replace

    monkeypatch.setattr(fitter, "fit", stopped_short)
    dropped2, _, records = _backward(fitter, sel, (), 0.01, False)
    assert dropped2 == dropped == ["dead_time"]
    assert records[0]["lr"] == 0.0 and records[0]["below_full"] == pytest.approx(5.0 - honest[0]["lr"] / 2, abs=0.05)
    assert honest[0]["below_full"] == 0.0
    err = capsys.readouterr().err
    assert "stopped in a worse minimum" in err and "fitted again from there" in err
    assert calls.count(full_key) == 2  # the full fit, and once more from the drop's basin: not again and again


def test_the_reports_carry_each_drop(flight):
    """``--json``'s ``backward_check`` lists each drop ``_backward`` made, with its test, beside ``dropped``; the text
    report says when a drop fit was below the fit with every effect."""
    import json

    from estimator.diagnose.runner import diagnose
    from reporting.diagnose_report import json_report, text_report

    fitter = CountFitter(flight.scenario, flight.frames, n_starts=2, quiet=True)
    dropped, _, records = _backward(fitter, _selection(fitter, ["dead_time", "background_gradient"]), (), 0.01, True)
    d = diagnose(flight, quiet=True, n_starts=2, jobs=1)
    d.dropped, d.backward = dropped, records
    j = json.loads(json.dumps(json_report(d)))
    assert j["dropped"] == ["dead_time"] and j["backward_check"] == records
    assert "stopped in a worse minimum" not in text_report(d)
    d.backward = [{**records[0], "below_full": 3.2}]
    assert "(by 3.2) than the fit with every effect" in text_report(d)


def test_a_full_fit_that_stopped_short_is_fitted_again_from_the_drops_basin(flight, capsys):
    """Injected: only the first fit with every effect comes back 5 above its minimum. The drop fit below it sends
    the full fit once more, from the drop's basin; that one is at the minimum, the drops are fitted again from it,
    and the check ends as with an honest full fit (the same drop, LR and nothing said about a worse minimum)."""
    from dataclasses import replace

    fitter = CountFitter(flight.scenario, flight.frames, n_starts=2, quiet=True)
    sel = _selection(fitter, ["dead_time", "background_gradient"])
    _, _, honest = _backward(fitter, sel, (), 0.01, True)
    fit, full_key, first = fitter.fit, ("dead_time", "background_gradient"), []

    def first_stopped_short(effects, *a, **k):
        res = fit(effects, *a, **k)
        if tuple(effects) == full_key and "init" in k and not first:
            first.append(res)
            return replace(res, nll=res.nll + 5.0)
        return res

    fitter.fit = first_stopped_short
    dropped, _, records = _backward(fitter, sel, (), 0.01, False)
    err = capsys.readouterr().err
    assert dropped == ["dead_time"] and "fitted again from there" in err
    assert "stopped in a worse minimum" not in err
    assert records[0]["below_full"] < 0.05  # the refit's minimum, to MIGRAD's tolerance
    assert records[0]["lr"] == pytest.approx(honest[0]["lr"], abs=0.1)


@pytest.fixture(scope="module")
def two_source_flight():
    # a second source 1300 cps at 1 m in the lattice's corner: its drop is decisive (LR ~300 against ~10)
    second = {"x": 1.5, "y": 1.5, "z": 0.0, "cps_at_1m": 1300.0, "nuclide": "Cs-137"}
    return simulate(FlightSpec(geometry="lattice", effects={"second_source": second}), seed=3)


def test_a_decisive_drop_is_not_fitted_again(two_source_flight, monkeypatch, capsys):
    """Named dead_time, air_attenuation and second_source on a two-source flight: the first round drops dead_time;
    second_source's drop was decisive there, so the second round fits only air_attenuation's drop, and the check
    ends as it does with every drop fitted. The bound it stood on holds on the fits: LR(second_source | without
    dead_time), fitted, is at least LR(second_source) - LR(dead_time) of the first round."""
    import math

    import estimator.diagnose.runner as runner

    def run(decisive: float):
        monkeypatch.setattr(runner, "DECISIVE_LR", decisive)
        fitter = CountFitter(two_source_flight.scenario, two_source_flight.frames, n_starts=2, quiet=True)
        sel = _selection(fitter, ["dead_time", "air_attenuation", "second_source"])
        nll: dict[str, float] = {}
        many = fitter.fit_many

        def recorded(tasks, *a, **k):
            fits, rest = many(tasks, *a, **k)
            nll.update({t.label: f.nll for t, f in zip(tasks, fits, strict=True)})
            return fits, rest

        fitter.fit_many = recorded
        return _backward(fitter, sel, (), 0.01, False), nll

    (dropped, reduced, records), fitted = run(runner.DECISIVE_LR)
    assert "kept without a new drop fit (decisive in an earlier round): second_source" in capsys.readouterr().err
    (dropped_all, reduced_all, records_all), fitted_all = run(math.inf)
    assert dropped == dropped_all == ["dead_time", "air_attenuation"] and records == records_all
    assert reduced.nll == reduced_all.nll and reduced.model.effects == ("second_source",)
    skipped = set(fitted_all) - set(fitted)
    assert skipped == {"baseline + air_attenuation + second_source without second_source"}
    full = "baseline + dead_time + air_attenuation + second_source"
    bound = 2.0 * (fitted[f"{full} without second_source"] - fitted[f"{full} without dead_time"])
    lr = 2.0 * (fitted_all[skipped.pop()] - fitted[f"{full} without dead_time"])
    assert bound > 200.0 and lr >= bound - 0.1  # to MIGRAD's tolerance
