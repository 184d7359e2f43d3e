"""A profiled search of many parameters starts with HESSE (``estimator.mle.HESSE_FIRST_PARAMS``): on a flight of the
independent forward model with two unmapped walls and a second source (every placement free, random-walk pose error,
so the offsets are profiled at every call), MIGRAD from the same start ends no more than 0.5 in -log L (one standard
deviation's worth) above where it ends without it. Both stop on a flat ridge (a wall's placement hangs on the source)
with EDM below tolerance; seen: with HESSE first 0.67 lower (seed 1) and 0.09 higher (seed 2)."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.forward2 import FlightSpec, random_unmapped_wall, simulate
from estimator import mle
from estimator.model import MeasurementModel, UnmappedWall

WALLS = ("unmapped_wall", "unmapped_wall_2")


def _flight(seed: int):
    spec = FlightSpec(geometry="lattice", pose_error="random_walk", scatter=0.02)
    fx = {"unmapped_wall": random_unmapped_wall(spec, seed, 0.5, np.random.default_rng(seed), 2),
          "second_source": {"x": 8.5, "y": 1.5, "z": 0.0, "cps_at_1m": 650.0}}
    return simulate(FlightSpec(geometry="lattice", pose_error="random_walk", scatter=0.02, effects=fx), seed=seed)


def _truth(ds, model: MeasurementModel) -> dict[str, float]:
    """The flight's true parameters in the model's terms (walls as placements seen from the source)."""
    src = ds.truth.sources[0]
    th = {**model.defaults(), "x": src.x, "y": src.y, "cps_at_1m": src.cps_at_1m,
          "background_cps": ds.scenario.background_cps}
    uw = ds.truth.effects["unmapped_wall"]
    for w, nm in zip(uw["walls"], WALLS, strict=False):
        placement = UnmappedWall.placement(np.array([*w["start"], *w["end"], w["thickness"], w["height"]]),
                                           np.array([src.x, src.y]))
        assert placement is not None
        th.update({f"{nm}.{k}": v for k, v in placement.items()})
        th[f"{nm}.mu_per_m"] = uw["mu_per_m"] * w["thickness"] / model.param(f"{nm}.thickness").value
    th.update({f"second_source.{k}": v for k, v in ds.truth.effects["second_source"].items() if k != "nuclide"})
    return th


@pytest.mark.slow
@pytest.mark.parametrize("seed", [2])  # the closer of the two (0.09 higher); each costs ~40 s of CPU
def test_hesse_first_reaches_a_minimum_at_least_as_low(seed):
    ds = _flight(seed)
    model = MeasurementModel(ds.scenario, ("second_source", *WALLS))
    names = model.free_names
    assert len(names) >= mle.HESSE_FIRST_PARAMS  # the fits this applies to: every placement free
    groups = mle.PoseGroups.from_frames(ds.frames, mle.declared_pose_error(model))
    assert groups.active.any()
    fixed = {p.name: p.value for p in model.params if p.fixed}
    fcn = mle._objective(model, ds.frames, names, fixed, groups)
    # off the truth by a few of each parameter's steps: the source 0.3 m away drags both walls with it
    start = dict(_truth(ds, model), x=_truth(ds, model)["x"] + 0.3)
    plain, first = (mle._search(fcn, model, names, start, hesse_first=h) for h in (False, True))
    for m in (plain, first):
        if not m.valid:  # as mle.fit does with a search that stopped short
            mle._polish(m)
    assert first.valid and plain.valid
    assert first.fval < plain.fval + 0.5
    # and near the truth's source, where the flight's counts put it
    truth = _truth(ds, model)
    assert np.hypot(first.values["x"] - truth["x"], first.values["y"] - truth["y"]) < 0.3
