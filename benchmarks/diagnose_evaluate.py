"""How well ``radseek diagnose`` names the missing effect on data it was not built from (issue 14).

    python -m benchmarks.diagnose_evaluate [--only shared|power|null|pairs|walls|nuclides|conull|offlist ...]
                                          [--seeds 2] [--nulls 60] [--conulls 60] [--starts 4] [--jobs 2]
                                          [--jsonl FILE] [--plot PNG] [--markdown MD]

Flights come from ``benchmarks.forward2``, a second forward model with its own code path (measured CsI(Tl)
spectra, event-by-event dead time, its own geometry, pose noise and gain drift; it imports neither the emulator
nor the estimator). Nothing in diagnose was tuned on them. Sections:

- ``shared``: the shared reference datasets (a regression set: each must still be diagnosed right);
- ``power``: every effect at four strengths (the shared datasets' strength among them), on two or more
  geometries and ``--seeds`` seeds: detection rate against strength and its 50 % point;
- ``null``: ``--nulls`` flights with no effect (every geometry, three crystals, both pose-error models,
  scattered-photon buildup): the false-alarm rate (target <= 2 % at alpha = 0.01);
- ``pairs``: two missing effects at once;
- ``walls`` (issue 30): 1-3 random unmapped walls (``forward2.random_unmapped_wall``) or a ``wall`` geometry's
  wall left out of the scenario, mu * t in {0.1, 0.2, 0.3, 0.5, 1.0}, ``--seeds`` per strength: how often
  ``unmapped_wall`` is named and whether a named wall's centre lies within 0.5 m of each true one;
- ``nuclides``: a second source of Co-60, Eu-152, Ba-133 (measured spectra) or Cs-137 at three strengths: is
  it named, and is ``second_source.nuclide`` right;
- ``conull``: ``--conulls`` flights with nothing diagnose should name, half with a Co-60 primary (its measured
  spectrum), random-walk and jittered pose errors, some over-dispersed (then ``over_dispersion`` is in truth and
  may be named): the false-alarm rate (target <= 2 %), an ``unexplained`` verdict counted as one;
- ``offlist``: physics diagnose has no name for (a moving source, a background drifting in time): is the verdict
  ``unexplained`` (target >= 90 %) with no wrong effect in ``missing``.

Rows read the ``--json`` report (``json_report``) with defaults, so this script runs before and after the
report gains ``unexplained``, ``partial``, ``residual_hotspots``, ``unmapped_walls`` and
``second_source.nuclide``.

For every flight with a named effect: does adding it bring deviance/dof to its expectation (within 3 sd), and
does it lower the source error (truth read for these columns only). Time per diagnose call is wall time on
whatever machine runs this (state the load).
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.shared_data import shared_path
from estimator.diagnose.shadow import crossings, seen_part
from estimator.diagnose.verdict import STRONG_AIC

SECTIONS = ("shared", "power", "null", "pairs", "walls", "nuclides", "conull", "offlist")
SHARED = ["lattice-clean", "lattice-wall", "close-pass-deadtime", "spin-anisotropy", "outdoor-air", "two-sources"]
SHARED_DIR = shared_path("datasets")

#: effect -> (geometries, strengths, the strength of the shared dataset / issue example, params(strength, rng))
POWER: dict[str, tuple[tuple[str, ...], tuple[float, ...], float | None, Callable[[float, Any], dict]]] = {
    "dead_time": (("closepass",), (1e-6, 3e-6, 6e-6, 1.2e-5), 1.2e-5, lambda v, r: {"tau_s": v}),
    "wall_attenuation": (("wall", "lshape"), (0.5, 1.0, 2.0, 3.0), 3.0, lambda v, r: {"mu_per_m": v}),
    "anisotropy": (("spin",), (0.1, 0.2, 0.35, 0.5), 0.5,
                   lambda v, r: {"fraction": v, "half_angle_deg": float(r.uniform(25, 45)), "edge_deg": 4.0}),
    "air_attenuation": (("outdoor",), (0.002, 0.005, 0.0093, 0.015), 0.0093, lambda v, r: {"mu_per_m": v}),
    "second_source": (("lattice", "lawnmower"), (150.0, 300.0, 650.0, 1300.0), 1300.0, None),
    "background_gradient": (("lawnmower", "lattice"), (0.5, 1.0, 2.0, 4.0), None, None),
    "gain_drift": (("lattice", "outdoor"), (0.15, 0.3, 0.6, 0.9), 0.9, lambda v, r: {"percent_per_min": v}),
    "pose_drift": (("lattice", "lawnmower"), (0.0005, 0.001, 0.002, 0.004), None, None),
    "over_dispersion": (("lattice", "spin"), (0.02, 0.05, 0.1, 0.2), None, lambda v, r: {"rel_sd": v}),
}
#: one outdoor survey (3000 frames, the slowest) in ten
NULL_GEOMETRIES = ("lattice", "spin", "lawnmower", "closepass", "wall", "lshape", "lattice", "spin", "lawnmower",
                   "outdoor")
CRYSTALS = ("real", "fill", "wide")
#: two missing effects at once
PAIRS = [
    ("wall", {"wall_attenuation": {"mu_per_m": 2.0}, "pose_drift": {"vx": 0.003, "vy": -0.002}}),
    ("spin", {"anisotropy": {"fraction": 0.5, "half_angle_deg": 30.0, "edge_deg": 4.0},
              "background_gradient": {"gx": 3.0, "gy": -2.0}}),
    ("closepass", {"dead_time": {"tau_s": 1.2e-5}, "gain_drift": {"percent_per_min": 0.9}}),
    ("outdoor", {"air_attenuation": {"mu_per_m": 0.0093}, "over_dispersion": {"rel_sd": 0.1}}),
    ("lattice", {"second_source": {"x": 8.5, "y": 1.5, "z": 0.0, "cps_at_1m": 1300.0},
                 "background_gradient": {"gx": -2.0, "gy": 3.0}}),
]
#: issue 30: unmapped walls' mu * thickness, the geometries they are flown on ("wall" = its wall left unmapped)
WALL_MU_T = (0.1, 0.2, 0.3, 0.5, 1.0)
WALL_GEOMETRIES = ("lattice", "spin", "wall")
#: second sources of other nuclides (measured spectra) and their strengths (cps at 1 m)
NUCLIDES = ("Co-60", "Eu-152", "Ba-133", "Cs-137")
NUCLIDE_STRENGTHS = (300.0, 650.0, 1300.0)
#: off-list physics: effect -> (strengths, params(strength, rng)); strength = |v| m/s or the drift's amplitude
#: (sine, period 20-60 s) or percent per minute (ramp)
OFFLIST: dict[str, tuple[tuple[float, ...], Callable[[float, Any], dict]]] = {
    # a source moving at constant v from t = 0 is the same counts as pose_drift at v (scored as that equivalence,
    # not as off-list); one picked up and carried off 30-60 % into the flight is off the list
    "moving_source": ((0.01, 0.02, 0.05), lambda v, r: _velocity(v, float(r.uniform(0, 2 * math.pi)))),
    "source_carried": ((0.02, 0.05, 0.1), lambda v, r: {**_velocity(v, float(r.uniform(0, 2 * math.pi))),
                                                        "start_fraction": float(r.uniform(0.3, 0.6))}),
    "background_drift": ((0.2, 0.4), lambda v, r: {"amplitude": v, "period_s": float(r.uniform(20, 60)),
                                                   "phase": float(r.uniform(0, 2 * math.pi))}),
    "background_ramp": ((10.0, 30.0), lambda v, r: {"percent_per_min": v}),
    # the same sine drift on a background a third of the counts (100 cps), where it shows in the data
    "background_drift_high": ((0.5, 0.8), lambda v, r: {"amplitude": v, "period_s": float(r.uniform(20, 60)),
                                                        "phase": float(r.uniform(0, 2 * math.pi))}),
    # picked up and walked off (0.5-1 m/s) 30-60 % into the flight: out of the counts within seconds (last: a
    # variant's seeds follow its place in this table, so new ones go at the end and the others fly as before)
    "source_taken": ((0.5, 1.0), lambda v, r: {**_velocity(v, float(r.uniform(0, 2 * math.pi))),
                                               "start_fraction": float(r.uniform(0.3, 0.6))}),
}
#: off-list effects flown on a higher background (cps)
OFFLIST_BACKGROUND = {"background_drift_high": 100.0}
OFFLIST_GEOMETRIES = ("lattice", "lawnmower", "spin")


def _velocity(v: float, ang: float) -> dict[str, float]:
    return {"vx": v * math.cos(ang), "vy": v * math.sin(ang)}


def _params(effect: str, v: float, rng: np.random.Generator, geometry: str) -> dict[str, float]:
    make = POWER[effect][3]
    if make is not None:
        return make(v, rng)
    ang = float(rng.uniform(0, 2 * np.pi))
    if effect == "background_gradient":
        return {"gx": v * math.cos(ang), "gy": v * math.sin(ang)}
    if effect == "pose_drift":
        return {"vx": v * math.cos(ang), "vy": v * math.sin(ang)}
    if effect == "second_source":  # a corner of the 10 m x 8 m area, >= 3 m from the primary (near the centre)
        corners = [(1.5, 1.5), (8.5, 1.5), (1.5, 6.5), (8.5, 6.5)]
        x, y = corners[int(rng.integers(4))]
        return {"x": x, "y": y, "z": 0.0, "cps_at_1m": v}
    raise KeyError(effect)


def jobs(which: list[str], seeds: int, nulls: int, conulls: int = 60) -> list[dict[str, Any]]:
    """The flights to run, as plain dicts (picklable for the process pool)."""
    out: list[dict[str, Any]] = []
    if "null" in which:
        for k in range(nulls):
            g = NULL_GEOMETRIES[k % len(NULL_GEOMETRIES)]
            spec = {"geometry": g, "effects": {}, "crystal": CRYSTALS[(k // 2) % 3],
                    "pose_error": "random_walk" if k % 4 == 3 else "independent", "scatter": 0.02 * (k % 3),
                    "dwell_s": 6.0}
            out.append({"kind": "null", "name": f"null-{g}-{k}", "spec": spec, "seed": 50_000 + k})
    if "power" in which:
        for e, (geoms, strengths, _, _) in POWER.items():
            for i, v in enumerate(strengths):
                for s in range(seeds):
                    seed = 1000 * (list(POWER).index(e) + 1) + 10 * i + s
                    rng = np.random.default_rng(seed)
                    g = geoms[(i + s) % len(geoms)]
                    fx = {e: _params(e, v, rng, g)}
                    spec = {"geometry": g, "effects": fx, "crystal": CRYSTALS[(i + s) % 3],
                            "pose_error": "random_walk" if (i + s) % 3 == 2 else "independent", "scatter": 0.02}
                    if e == "gain_drift" and g == "lattice":
                        spec["cps_at_1m"] = 3000.0  # the case: a strong source, 12 s dwells
                        spec["dwell_s"] = 12.0
                    out.append({"kind": "power", "name": f"{e}-{v:g}-{g}-s{s}", "effect": e, "strength": v,
                                "spec": spec, "seed": seed})
    if "pairs" in which:
        for k, (g, fx) in enumerate(PAIRS):
            out.append({"kind": "pairs", "name": "+".join(fx) + f"-{g}", "spec": {"geometry": g, "effects": fx,
                        "crystal": CRYSTALS[k % 3], "scatter": 0.02}, "seed": 70_000 + k})
    if "shared" in which:
        out += [{"kind": "shared", "name": n} for n in SHARED if (SHARED_DIR / n).is_dir()]
    if "walls" in which:
        out += wall_jobs(seeds)
    if "nuclides" in which:
        out += nuclide_jobs(seeds)
    if "conull" in which:
        out += conull_jobs(conulls)
    if "offlist" in which:
        out += offlist_jobs(seeds)
    return out


def wall_jobs(seeds: int) -> list[dict[str, Any]]:
    """Unmapped walls: per mu * t, ``seeds`` flights cycling lattice / spin (1-3 random slabs) and the ``wall``
    geometry with its wall left out of the scenario."""
    from benchmarks.forward2 import FlightSpec, random_unmapped_wall

    out = []
    for i, mt in enumerate(WALL_MU_T):
        for s in range(seeds):
            seed = 80_000 + 100 * i + s
            rng = np.random.default_rng(seed)
            g = WALL_GEOMETRIES[(i + s) % len(WALL_GEOMETRIES)]
            spec: dict[str, Any] = {"geometry": g, "effects": {}, "crystal": CRYSTALS[(i + s) % 3],
                                    "pose_error": "random_walk" if (i + s) % 4 == 3 else "independent",
                                    "scatter": 0.02}
            if g == "wall":
                spec["unmap_walls"] = True
                spec["effects"] = {"unmapped_wall": {"mu_per_m": mt / 0.2}}  # the geometry's wall is 0.2 m thick
                n = 1
            else:
                uw = random_unmapped_wall(FlightSpec(**spec), seed, mt, rng, 1 + (i + 2 * s) % 3)
                spec["effects"] = {"unmapped_wall": uw}
                n = len(uw["walls"])
            out.append({"kind": "walls", "name": f"uwall-{mt:g}-{g}-n{n}-s{s}", "effect": "unmapped_wall",
                        "strength": mt, "spec": spec, "seed": seed})
    return out


def nuclide_jobs(seeds: int) -> list[dict[str, Any]]:
    """Second sources of each nuclide at each strength, ``seeds`` flights (lattice / lawnmower)."""
    out = []
    for a, nuc in enumerate(NUCLIDES):
        for i, v in enumerate(NUCLIDE_STRENGTHS):
            for s in range(seeds):
                seed = 90_000 + 1000 * a + 10 * i + s
                rng = np.random.default_rng(seed)
                g = ("lattice", "lawnmower")[(i + s) % 2]
                fx = {"second_source": {**_params("second_source", v, rng, g), "nuclide": nuc}}
                spec = {"geometry": g, "effects": fx, "crystal": ("real", "wide")[s % 2], "scatter": 0.02,
                        "pose_error": "random_walk" if (i + s) % 3 == 2 else "independent"}
                out.append({"kind": "nuclides", "name": f"nuc-{nuc}-{v:g}-{g}-s{s}", "effect": "second_source",
                            "strength": v, "nuclide": nuc, "spec": spec, "seed": seed})
    return out


def conull_jobs(n: int) -> list[dict[str, Any]]:
    """Nulls: Co-60 primaries (even k) and Cs-137 ones (odd k), random-walk (every other pair) or jittered
    pose errors, every third over-dispersed (rel_sd 0.03-0.08: then ``over_dispersion`` is the truth)."""
    out = []
    for k in range(n):
        g = NULL_GEOMETRIES[(k // 2) % len(NULL_GEOMETRIES)]
        nuc = "Co-60" if k % 2 == 0 else "Cs-137"
        rng = np.random.default_rng(60_000 + k)
        fx = {"over_dispersion": {"rel_sd": float(rng.uniform(0.03, 0.08))}} if k % 3 == 2 else {}
        spec = {"geometry": g, "effects": fx, "nuclide": nuc,
                "crystal": ("real", "wide")[(k // 2) % 2] if nuc == "Co-60" else CRYSTALS[(k // 2) % 3],
                "pose_error": "random_walk" if (k // 2) % 2 == 1 else "independent", "scatter": 0.02 * (k % 3),
                "dwell_s": 6.0}
        out.append({"kind": "conull", "name": f"conull-{nuc}-{g}-{k}", "spec": spec, "seed": 60_000 + k,
                    "nuclide": nuc})
    return out


def offlist_jobs(seeds: int) -> list[dict[str, Any]]:
    """Off-list physics: a moving source, a sine-drifting and a ramping background."""
    out = []
    for a, (e, (strengths, make)) in enumerate(OFFLIST.items()):
        for i, v in enumerate(strengths):
            for s in range(seeds):
                seed = 95_000 + 1000 * a + 10 * i + s
                g = OFFLIST_GEOMETRIES[(i + s) % len(OFFLIST_GEOMETRIES)]
                effect = {"background_": "background_drift", "source_": "moving_source"}.get(e[:e.index("_") + 1], e)
                spec = {"geometry": g, "effects": {effect: make(v, np.random.default_rng(seed))},
                        "crystal": CRYSTALS[(i + s) % 3], "scatter": 0.02}
                if e in OFFLIST_BACKGROUND:
                    spec["background_cps"] = OFFLIST_BACKGROUND[e]
                out.append({"kind": "offlist", "name": f"off-{e}-{v:g}-{g}-s{s}", "effect": effect, "variant": e,
                            "strength": v, "spec": spec, "seed": seed})
    return out


def run_one(job: dict[str, Any], n_starts: int = 4) -> dict[str, Any]:
    from estimator.diagnose.runner import diagnose
    from radseek_io.truth import read_dataset_with_truth
    from reporting.diagnose_report import json_report
    from reporting.truth_errors import score_diagnosis

    if job["kind"] == "shared":
        ds = read_dataset_with_truth(SHARED_DIR / job["name"])
    else:
        from benchmarks.forward2 import FlightSpec, simulate

        ds = simulate(FlightSpec(**job["spec"]), seed=job["seed"])
    t0, c0 = time.perf_counter(), time.process_time()
    d = score_diagnosis(diagnose(ds, quiet=True, n_starts=n_starts), ds.truth)
    secs, cpu = time.perf_counter() - t0, time.process_time() - c0
    fx = ds.truth.effects if ds.truth else {}
    missed_second = "second_source" in fx and "second_source" not in d.final.fit.model.effects
    gap = truth_model_gap(ds, d.final.fit) if ds.truth and ("start_fraction" in fx.get("moving_source", {})
                                                           or "background_drift" in fx or missed_second) else None
    first = d.selection.first
    chosen = [st.candidates[0] for st in d.selection.steps if st.chosen]
    after = d.after
    truth = sorted(ds.truth.effects) if ds.truth else []
    ref = after or d.current
    j = json_report(d)
    return {
        **{k: job[k] for k in ("kind", "name", "effect", "variant", "strength", "nuclide") if k in job},
        "frames": len(ds.frames),
        "truth": truth,
        "named": list(j.get("missing", d.selection.missing)),
        **open_world_fields(j, ds.truth.effects if ds.truth else {}, ds.scenario.nuclide,
                            np.array([ds.truth.sources[0].x, ds.truth.sources[0].y]) if ds.truth else None,
                            np.c_[ds.frames.x, ds.frames.y]),
        "p_values": [float(c.p_value) for c in chosen],
        "top": first[0].effect if first else None,
        "top_log10_p": round(first[0].log10_p, 2) if first else None,
        "dev_before": round(d.current.gof.deviance_per_dof, 4),
        "dev_after": round(after.gof.deviance_per_dof, 4) if after else None,
        "dev_expected": round(ref.gof.expected_per_dof, 4),
        "dev_sd": round(ref.gof.sd_per_dof, 4),
        "dev_expected_before": round(d.current.gof.expected_per_dof, 4),
        "dev_sd_before": round(d.current.gof.sd_per_dof, 4),
        "err_before": None if d.current.source_error_m is None else round(d.current.source_error_m, 3),
        "err_after": None if not after or after.source_error_m is None else round(after.source_error_m, 3),
        "params": {k: [float(f"{v:.4g}"), float(f"{e:.3g}") if math.isfinite(e) else None]
                   for c in chosen for k, (v, e) in ((k, (c.params[k], c.errors.get(k, math.nan))) for k in c.params)},
        "truth_params": ds.truth.effects if ds.truth else {},
        "truth_model": gap,
        "source_motion": j.get("source_motion"),
        "background_time": j.get("background_time"),
        "seconds": round(secs, 1),
        "cpu_seconds": round(cpu, 1),
    }


# ------------------------------------------------------------------------------------------- open world (30)


#: the true model is told apart from the named one when its AIC is lower by at least this (strong support)
TOLD_APART_AIC = STRONG_AIC


def truth_model_gap(ds: Any, named: Any) -> dict[str, Any]:
    """How much better the truth fits the counts than the model diagnose named, both with the same pose-offset
    profile: a source carried off from ``start_fraction`` of the flight (``source_motion``, t0 the truth's), a
    background drifting in time (``background_drift``, the truth's period and phase, its amplitude or ramp free), or
    a second source diagnose did not name (``second_source``, its place and strength free), fitted from the truth
    and from the named fit's values. An AIC gap below :data:`TOLD_APART_AIC` (or negative) means the counts cannot
    tell the truth from the named effects: no verdict could call it unexplained (or name the second source, and
    so its nuclide) from them."""
    from estimator.diagnose.backend import split_transit_legs
    from estimator.mle import fit
    from estimator.model import MeasurementModel

    frames = split_transit_legs(ds.frames)
    fx = ds.truth.effects
    src = ds.truth.sources[0]
    truth = {"x": src.x, "y": src.y, "cps_at_1m": src.cps_at_1m, "background_cps": ds.truth.background_cps}
    if "moving_source" in fx:
        mv = fx["moving_source"]
        fixed = {"source_motion.t0": float(mv.get("start_s", mv["start_fraction"] * float(ds.frames.t[-1])))}
        truth.update({"source_motion.vx": mv["vx"], "source_motion.vy": mv["vy"]})
        effect, shown = "source_motion", ("source_motion.vx", "source_motion.vy")
    elif "second_source" in fx:
        fixed = {}
        truth.update({f"second_source.{k}": float(fx["second_source"][k]) for k in ("x", "y", "cps_at_1m")})
        effect, shown = "second_source", ("second_source.x", "second_source.y", "second_source.cps_at_1m")
    else:
        bd = fx["background_drift"]
        fixed = {"background_drift.period_s": float(bd.get("period_s", 60.0)),
                 "background_drift.phase": float(bd.get("phase", 0.0))}
        free = "background_drift.amplitude" if bd.get("amplitude") else "background_drift.percent_per_min"
        other = ({"background_drift.amplitude", "background_drift.percent_per_min"} - {free}).pop()
        fixed[other] = 0.0
        truth[free] = float(bd.get(free.split(".")[1], 0.0))
        effect, shown = "background_drift", (free,)
    model = MeasurementModel(ds.scenario, (effect,))
    if fixed:
        model = model.with_params(**{k: {"value": v, "fixed": True} for k, v in fixed.items()})
    from_named = {**{k: v for k, v in named.values.items() if k in model.param_names}, **fixed}
    res = fit(model, frames, n_starts=2, init={**truth, **fixed}, more_inits=[from_named])
    k_truth, k_named = len(res.free_names), len(named.free_names)
    aic_gap = 2 * (named.nll - res.nll) + 2 * (k_named - k_truth)
    return {"effect": effect, "nll_gap": round(named.nll - res.nll, 2), "k_truth": k_truth, "k_named": k_named,
            "aic_gap": round(aic_gap, 2), "told_apart": bool(aic_gap >= TOLD_APART_AIC),
            "fitted": {k: round(res.values[k], 4) for k in shown},
            "fitted_err": {k: round(float(res.errors.get(k, math.nan)), 4) for k in shown}}


def named_nuclide(j: dict[str, Any]) -> str | None:
    """The second source's nuclide in a ``--json`` report: ``effect_params["second_source.nuclide"]`` of the
    final model, else of ``with_missing``, else a ``second_source`` candidate's ``nuclide`` param; None if absent."""
    for model in (j, j.get("with_missing") or {}):
        v = (model.get("effect_params") or {}).get("second_source.nuclide", {})
        if isinstance(v, dict) and v.get("value") is not None:
            return str(v["value"])
    steps = [c for st in j.get("selection_steps", []) for c in st.get("candidates", [])]
    for c in [*j.get("candidates", []), *steps]:
        if c.get("effect") == "second_source" and (c.get("params") or {}).get("nuclide") is not None:
            return str(c["params"]["nuclide"])
    return None


def segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance of points ``p`` (..., 2) from the segment a-b."""
    ab = np.asarray(b, float) - np.asarray(a, float)
    f = np.clip(np.sum((np.asarray(p, float) - a) * ab, axis=-1) / max(float(ab @ ab), 1e-12), 0.0, 1.0)
    return np.linalg.norm(np.asarray(p, float) - (a + f[..., None] * ab), axis=-1)


def wall_errors(true_walls: list[dict], named_walls: list[dict]) -> list[dict[str, float]]:
    """Per true wall: ``segment`` = distance from its segment to the nearest named wall's centre, ``centre`` =
    distance from its centre to the nearest named centre (each nearest on its own terms), ``shaded_centre`` (when
    the true wall carries its ``shaded`` part, :func:`shaded_part`) = from that part's centre, and ``seen_shaded``
    (when the named walls carry the ``seen_part`` diagnose reports) = from that part's centre to the nearest named
    wall's seen part's centre: what the counts can locate on either side; [] if none named."""
    if not named_walls or not true_walls:
        return []

    def mid(w: dict) -> np.ndarray:
        return (np.asarray(w["start"], float)[:2] + np.asarray(w["end"], float)[:2]) / 2

    c = np.array([mid(w) for w in named_walls])
    seen = [mid(w["seen_part"]) for w in named_walls if w.get("seen_part")]
    out = []
    for w in true_walls:
        a, b = np.asarray(w["start"], float), np.asarray(w["end"], float)
        row = {"segment": round(float(segment_distance(c, a, b).min()), 3),
               "centre": round(float(np.linalg.norm(c - (a + b) / 2, axis=1).min()), 3)}
        if w.get("shaded"):
            m = mid(w["shaded"])
            row["shaded_centre"] = round(float(np.linalg.norm(c - m, axis=1).min()), 3)
            if seen:
                row["seen_shaded"] = round(float(np.linalg.norm(np.array(seen) - m, axis=1).min()), 3)
        out.append(row)
    return out


def placement_range(source_xy: np.ndarray, wall: dict, frames_xy: np.ndarray) -> tuple[float, float]:
    """The slab's placements the flown geometry cannot tell from the true one: the range of its centre's shift
    (m, along the line from the source; negative = towards the source) under scalings about the source that
    leave every frame's side of the slab unchanged.

    Scaled about the source by k, a slab keeps its direction and the angle each line of sight meets it at, so
    the path through it (thickness / cos) and the sector it shades are the same: the shadow changes only where a
    frame inside that sector changes side. A frame whose line of sight meets the slab's line at a fraction s of
    the way from the source is shaded for every k <= 1 / s, so the shade is the same for
    1 / min(s > 1) < k <= 1 / max(s <= 1). With no frame inside the sector between the source and the slab the
    slab can slide all the way to the source (k -> 0). Heights are ignored (walls above every line of sight)."""
    s, u = crossings(source_xy, wall["start"], wall["end"], frames_xy)
    inside = (s > 0) & (u >= 0) & (u <= 1)
    shaded, lit = s[inside & (s <= 1)], s[inside & (s > 1)]
    k_hi = 1.0 / shaded.max() if len(shaded) else np.inf
    k_lo = 1.0 / lit.min() if len(lit) else 0.0
    mid = (np.asarray(wall["start"], float)[:2] + np.asarray(wall["end"], float)[:2]) / 2
    r = float(np.linalg.norm(mid - np.asarray(source_xy, float)[:2]))
    return round((k_lo - 1.0) * r, 3), round(min(k_hi - 1.0, 1e3) * r, 3)


def shaded_part(source_xy: np.ndarray, wall: dict, frames_xy: np.ndarray) -> dict | None:
    """The part of a true slab that some frame's line of sight from the true source crosses
    (``estimator.diagnose.shadow.seen_part``, which diagnose reports for its named walls): the only part the counts
    can locate; None if it shades none."""
    return seen_part(source_xy, wall["start"], wall["end"], frames_xy)


def open_world_fields(j: dict[str, Any], truth_effects: dict[str, Any], primary: str,
                      source_xy: np.ndarray | None = None, frames_xy: np.ndarray | None = None) -> dict[str, Any]:
    """Row fields for issue 30 from a ``--json`` report (``.get`` defaults: the report may not have them yet).
    With the true source and the frames' positions, each true wall's ``placement_range_m``
    (:func:`placement_range`)."""
    named = list(j.get("unmapped_walls", []) or [])
    true_walls = (truth_effects.get("unmapped_wall") or {}).get("walls", [])
    if source_xy is not None and frames_xy is not None:
        true_walls = [{**w, "shaded": shaded_part(source_xy, w, frames_xy)} for w in true_walls]
    ss = truth_effects.get("second_source")
    return {
        "unexplained": bool(j.get("unexplained", False)),
        "partial": list(j.get("partial", []) or []),
        "hotspots": len(j.get("residual_hotspots", []) or []),
        "walls_named": len(named),
        "walls_est": [{"start": w.get("start"), "end": w.get("end"), "mu_per_m": w.get("mu_per_m"),
                       "thickness": w.get("thickness"), "errors": w.get("errors"), "seen_part": w.get("seen_part")}
                      for w in named],
        "wall_centre_err_m": wall_errors(true_walls, named),
        "placement_range_m": ([list(placement_range(source_xy, w, frames_xy)) for w in true_walls]
                              if source_xy is not None and frames_xy is not None else []),
        "nuclide_named": named_nuclide(j),
        "nuclide_true": (ss.get("nuclide", primary) if ss else None),
        "primary_nuclide": primary,
    }


def walls_table(rows: list[dict], within_m: float = 0.5) -> tuple[str, dict]:
    """Per mu * t: flights where ``unmapped_wall`` was named; true walls with a named centre within
    ``within_m`` of their segment / their centre / the centre of their shaded part (the part some line of sight
    crosses, :func:`shaded_part`: the rest of a slab shades nothing, so no count can place it); flights with every
    true wall so located; flights where some true wall has a named centre within ``within_m`` of its centre (the
    target read per flight: "a wall named in >= 90 % of flights with its centre within 0.5 m"); extra walls named
    (a named centre > 1 m from every true segment); flights naming another effect."""
    by: dict[float, list[dict]] = {}
    for r in rows:
        if r["kind"] == "walls":
            by.setdefault(r["strength"], []).append(r)
    lines = [f"| mu x t | flights | unmapped_wall named | true walls located within {within_m:g} m: of its "
             "segment / of its centre / of its shaded part's centre / that centre by a named wall's seen part | "
             "flights with every wall located (segment) | "
             "flights with a wall located (centre) | walls named (true) | others named | unexplained |",
             "|---|---|---|---|---|---|---|---|---|"]
    summary: dict[float, dict] = {}
    for mt in sorted(by):
        rs = by[mt]
        det = sum("unmapped_wall" in r["named"] or r.get("walls_named", 0) > 0 for r in rs)
        errs = [e for r in rs for e in r.get("wall_centre_err_m", [])]
        n_true = max(sum(len(r.get("truth_params", {}).get("unmapped_wall", {}).get("walls", [])) for r in rs), 1)
        seg = sum(e["segment"] <= within_m for e in errs)
        cen = sum(e["centre"] <= within_m for e in errs)
        sha = sum(e.get("shaded_centre", e["centre"]) <= within_m for e in errs)
        see = sum(e.get("seen_shaded", math.inf) <= within_m for e in errs)
        every = sum(bool(r.get("wall_centre_err_m")) and all(e["segment"] <= within_m for e in r["wall_centre_err_m"])
                    for r in rs)
        some = sum(any(e["centre"] <= within_m for e in r.get("wall_centre_err_m", [])) for r in rs)
        others = sum(any(n not in r["truth"] for n in r["named"]) for r in rs)
        named = sum(r.get("walls_named", 0) for r in rs)
        unexp = sum(bool(r.get("unexplained")) for r in rs)
        lines.append(f"| {mt:g} | {len(rs)} | {det}/{len(rs)} ({det / len(rs):.0%}) | {seg}/{n_true} / "
                     f"{cen}/{n_true} / {sha}/{n_true} / {see}/{n_true} | {every}/{len(rs)} | {some}/{len(rs)} | "
                     f"{named} ({n_true}) | {others} | {unexp} |")
        summary[mt] = {"n": len(rs), "detected": det / len(rs), "located_segment": seg / n_true,
                       "located_centre": cen / n_true, "located_shaded": sha / n_true, "located_seen": see / n_true,
                       "every_located": every / len(rs), "flights_located": some / len(rs)}
    strong = [v for mt, v in summary.items() if mt >= 0.3]
    if strong:
        det = min(v["detected"] for v in strong)
        loc = min(v["located_centre"] for v in strong)
        sha = min(v["located_shaded"] for v in strong)
        see = min(v["located_seen"] for v in strong)
        fl = min(v["flights_located"] for v in strong)
        lines.append(f"\nTarget (mu x t >= 0.3 named in >= 90 % with centre within {within_m:g} m): lowest detection "
                     f"{det:.0%}, lowest located (centre) {loc:.0%}, (shaded part's centre) {sha:.0%}, (that "
                     f"centre by a named wall's seen part) {see:.0%}: "
                     f"{'met' if det >= 0.9 and loc >= 0.9 else 'NOT met'} per true wall; lowest share of flights "
                     f"with a wall located {fl:.0%}: {'met' if det >= 0.9 and fl >= 0.9 else 'NOT met'} per flight.")
    return "\n".join(lines), summary


def nuclides_table(rows: list[dict]) -> tuple[str, dict]:
    """Per true nuclide of the second source: flights where ``second_source`` was named, where the named
    nuclide is the true one (among those named and over all flights), and, for the flights where it was not named,
    whether the counts could have told it from the model diagnose kept (``truth_model``: the true second source
    fitted, AIC better by :data:`TOLD_APART_AIC`): the share right of the flights whose second source the counts
    show (named, or told apart)."""
    by: dict[str, list[dict]] = {}
    for r in rows:
        if r["kind"] == "nuclides":
            by.setdefault(r.get("nuclide_true") or r.get("nuclide") or "?", []).append(r)
    lines = ["| nuclide | flights | second_source named | nuclide right (of named) | nuclide right (all) | "
             "named as | missed, told apart by the counts (AIC gap) | nuclide right (of those the counts show) |",
             "|---|---|---|---|---|---|---|---|"]
    summary: dict[str, dict] = {}
    for nuc in sorted(by):
        rs = by[nuc]
        det = [r for r in rs if "second_source" in r["named"]]
        right = sum(r.get("nuclide_named") == nuc for r in det)
        as_ = sorted({str(r.get("nuclide_named")) for r in det})
        missed = [r for r in rs if r not in det]
        gaps = [r["truth_model"] for r in missed if r.get("truth_model")]
        apart = sum(g["told_apart"] for g in gaps)
        shown = len(det) + apart
        aics = ", ".join(f"{g['aic_gap']:+.0f}" for g in gaps)
        told = (f"{apart}/{len(missed)} ({aics})" if gaps
                else f"-/{len(missed)}" if missed else "-")
        lines.append(f"| {nuc} | {len(rs)} | {len(det)}/{len(rs)} | {right}/{len(det)} | {right}/{len(rs)} "
                     f"({right / len(rs):.0%}) | {', '.join(as_) or '-'} | {told} | "
                     f"{right}/{shown}{f' ({right / shown:.0%})' if shown else ''} |")
        summary[nuc] = {"n": len(rs), "detected": len(det) / len(rs), "right": right / len(rs),
                        "right_of_named": right / len(det) if det else None,
                        "right_of_shown": right / shown if shown and len(gaps) == len(missed) else None}
    if summary:
        low = min(v["right"] for v in summary.values())
        lines.append(f"\nTarget (nuclide right >= 90 %): lowest {low:.0%}: {'met' if low >= 0.9 else 'NOT met'}.")
        of_shown = [v["right_of_shown"] for v in summary.values() if v["right_of_shown"] is not None]
        if of_shown:
            lines.append(f"Of the flights whose second source the counts show (named, or the true one fitted better "
                         f"by an AIC of {TOLD_APART_AIC:g}): lowest {min(of_shown):.0%}.")
    return "\n".join(lines), summary


#: off-list variants whose counts are exactly those of an effect in the vocabulary: variant -> that effect
EQUIVALENT = {"moving_source": "pose_drift"}


def equivalent_named(r: dict) -> bool:
    """A constant-velocity moving source named as its equivalent ``pose_drift`` (recorded = true + v t is the
    same relative geometry as a source at src0 + v t) with the fitted v within 3 sd (+ 2 mm/s) of the truth's."""
    eff = EQUIVALENT.get(r.get("variant", ""))
    if eff is None or r["named"] != [eff]:
        return False
    v = r["truth_params"]["moving_source"]
    fit = r["params"]
    return all(abs(fit[f"{eff}.{k}"][0] - v[k]) <= 3 * (fit[f"{eff}.{k}"][1] or math.inf) + 0.002
               for k in ("vx", "vy"))


def offlist_table(rows: list[dict]) -> tuple[str, dict]:
    """Per off-list effect: flights with ``unexplained`` true, and flights where ``missing`` lists any effect
    (all are wrong there: nothing in diagnose's vocabulary is the truth). Variants with an exact equivalent in
    the vocabulary (:data:`EQUIVALENT`) get their own lines: named as that equivalent with the true values, or not."""
    by: dict[str, list[dict]] = {}
    eq: dict[str, list[dict]] = {}
    for r in rows:
        if r["kind"] == "offlist":
            v = r.get("variant", r["effect"])
            (eq if v in EQUIVALENT else by).setdefault(v, []).append(r)
    lines = ["| off-list effect | flights | unexplained | a wrong effect in missing (named) | residual hotspots "
             "| truth told apart by the counts (AIC) | unexplained of those |",
             "|---|---|---|---|---|---|---|"]
    summary: dict[str, dict] = {}
    for e in sorted(by):
        rs = by[e]
        unexp = sum(bool(r.get("unexplained")) for r in rs)
        wrong = [r for r in rs if any(n not in r["truth"] for n in r["named"])]
        names = sorted({n for r in wrong for n in r["named"] if n not in r["truth"]})
        hot = sum(r.get("hotspots", 0) > 0 for r in rs)
        gaps = [r for r in rs if r.get("truth_model")]
        apart = [r for r in gaps if r["truth_model"]["told_apart"]]
        told = (f"{len(apart)}/{len(gaps)} (AIC gap {min(r['truth_model']['aic_gap'] for r in gaps):+.0f} to "
                f"{max(r['truth_model']['aic_gap'] for r in gaps):+.0f})") if gaps else "-"
        of_apart = f"{sum(bool(r.get('unexplained')) for r in apart)}/{len(apart)}" if apart else "-"
        lines.append(f"| {e} | {len(rs)} | {unexp}/{len(rs)} ({unexp / len(rs):.0%}) | {len(wrong)}"
                     f"{' (' + ', '.join(names) + ')' if names else ''} | {hot}/{len(rs)} | {told} | {of_apart} |")
        summary[e] = {"n": len(rs), "unexplained": unexp / len(rs), "wrong": len(wrong),
                      "told_apart": len(apart) if gaps else None}
    if summary:
        n = sum(v["n"] for v in summary.values())
        unexp = sum(v["unexplained"] * v["n"] for v in summary.values()) / n
        wrong = sum(v["wrong"] for v in summary.values())
        lines.append(f"\nTarget (unexplained in >= 90 % of off-list flights, no wrong effect in missing): "
                     f"{unexp:.0%}, {wrong} wrong: {'met' if unexp >= 0.9 and wrong == 0 else 'NOT met'}.")
    for v, rs in sorted(eq.items()):
        ok = sum(equivalent_named(r) for r in rs)
        summary[f"{v} (= {EQUIVALENT[v]})"] = {"n": len(rs), "equivalent_named": ok}
        lines.append(f"\n{v} at constant velocity is the same counts as `{EQUIVALENT[v]}`: named as it, with the "
                     f"true velocity within 3 sd, in {ok}/{len(rs)}.")
    return "\n".join(lines), summary


def open_world_curves(rows: list[dict]) -> dict[str, dict]:
    """Power curves for the plot: ``unmapped_wall`` named against mu * t, and per nuclide the second source
    named with the right nuclide against its strength."""
    out: dict[str, dict] = {}
    groups: dict[str, dict[float, list[bool]]] = {}
    for r in rows:
        if r["kind"] == "walls":
            hit = "unmapped_wall" in r["named"] or r.get("walls_named", 0) > 0
            groups.setdefault("unmapped_wall", {}).setdefault(r["strength"], []).append(hit)
        elif r["kind"] == "nuclides":
            nuc = r.get("nuclide_true") or r.get("nuclide")
            hit = "second_source" in r["named"] and r.get("nuclide_named") == nuc
            groups.setdefault(f"second_source {nuc}", {}).setdefault(r["strength"], []).append(hit)
    for name, by in groups.items():
        ss = sorted(by)
        rates = [sum(by[v]) / len(by[v]) for v in ss]
        out[name] = {"strengths": ss, "rates": rates, "p50": fifty_percent_point(ss, rates)}
    return out


def false_alarm(r: dict) -> bool:
    """A null flight's false alarm: ``missing`` names an effect not in truth, or the verdict is ``unexplained``."""
    return any(n not in r["truth"] for n in r["named"]) or bool(r.get("unexplained"))


def conull_table(rows: list[dict], target: float = 0.02) -> tuple[str, dict]:
    """False alarms on the conull flights, overall and per primary nuclide."""
    rs = [r for r in rows if r["kind"] == "conull"]
    if not rs:
        return "", {}
    by: dict[str, list[dict]] = {}
    for r in rs:
        by.setdefault(r.get("primary_nuclide") or r.get("nuclide") or "?", []).append(r)
    lines = ["| primary | flights | false alarms | of them unexplained | named |", "|---|---|---|---|---|"]
    summary: dict[str, Any] = {}
    for nuc in sorted(by):
        fa = [r for r in by[nuc] if false_alarm(r)]
        names = sorted({n for r in fa for n in r["named"] if n not in r["truth"]})
        lines.append(f"| {nuc} | {len(by[nuc])} | {len(fa)} ({len(fa) / len(by[nuc]):.1%}) | "
                     f"{sum(bool(r.get('unexplained')) for r in fa)} | {', '.join(names) or '-'} |")
        summary[nuc] = {"n": len(by[nuc]), "false_alarms": len(fa)}
    n_fa = sum(false_alarm(r) for r in rs)
    rate = n_fa / len(rs)
    summary["all"] = {"n": len(rs), "false_alarms": n_fa, "rate": rate}
    lines.append(f"\nFalse alarms {n_fa}/{len(rs)} ({rate:.1%}; target <= {target:.0%}): "
                 f"{'met' if rate <= target else 'NOT met'}"
                 + (f" ({', '.join(r['name'] for r in rs if false_alarm(r))})" if n_fa else "") + ".")
    return "\n".join(lines), summary


# ------------------------------------------------------------------------------------------- summaries


def fifty_percent_point(strengths: list[float], rates: list[float]) -> float | None:
    """Strength where the detection rate crosses 50 % (log-linear interpolation), None if never crossed."""
    pts = sorted(zip(strengths, rates, strict=True))
    for (s0, r0), (s1, r1) in zip(pts[:-1], pts[1:], strict=True):
        if r0 < 0.5 <= r1:
            f = (0.5 - r0) / (r1 - r0)
            return float(math.exp(math.log(s0) + f * (math.log(s1) - math.log(s0))))
    if pts and pts[0][1] >= 0.5:
        return float(pts[0][0])  # already found at the weakest strength: an upper bound
    return None


def power_table(rows: list[dict]) -> tuple[str, dict]:
    curves: dict[str, dict[float, list[dict]]] = {}
    for r in rows:
        if r["kind"] == "power":
            curves.setdefault(r["effect"], {}).setdefault(r["strength"], []).append(r)
    lines = ["| effect | detection rate per strength (n flights) | 50 % point | at the shared strength | "
             "others named | dev/dof after within 3 sd | source error lowered |",
             "|---|---|---|---|---|---|---|"]
    summary: dict[str, Any] = {}
    for e, by in curves.items():
        ss = sorted(by)
        rates = [sum(e in r["named"] for r in by[s]) / len(by[s]) for s in ss]
        p50 = fifty_percent_point(ss, rates)
        shared = POWER[e][2]
        at = f"{rates[ss.index(shared)]:.0%}" if shared in ss else "-"
        wrong = sum(len([n for n in r["named"] if n not in r["truth"]]) > 0 for s in ss for r in by[s])
        found = [r for s in ss for r in by[s] if e in r["named"] and r["dev_after"] is not None]
        ok = sum(abs(r["dev_after"] - r["dev_expected"]) <= 3 * r["dev_sd"] for r in found)
        lowered = [r for r in found if r["err_before"] is not None and r["err_after"] is not None]
        low = sum(r["err_after"] <= r["err_before"] + 0.005 for r in lowered)
        n_all = sum(len(by[s]) for s in ss)
        cells = ", ".join(f"{s:g}: {rt:.0%} ({len(by[s])})" for s, rt in zip(ss, rates, strict=True))
        p50_txt = "-" if p50 is None else (f"<= {p50:.3g}" if rates[0] >= 0.5 else f"{p50:.3g}")
        lines.append(f"| {e} | {cells} | {p50_txt} | {at} | {wrong}/{n_all} | "
                     f"{ok}/{len(found)} | {low}/{len(lowered)} |")
        summary[e] = {"strengths": ss, "rates": rates, "p50": p50}
    return "\n".join(lines), summary


def rows_table(rows: list[dict]) -> str:
    lines = ["| flight | truth | named | deviance/dof before -> after (expected +- sd) | source error before -> "
             "after [m] | s |", "|---|---|---|---|---|---|"]
    for r in rows:
        dev = f"{r['dev_before']} -> {r['dev_after'] if r['dev_after'] is not None else '-'} " \
              f"({r['dev_expected']} +- {r['dev_sd']})"
        err = f"{r['err_before']} -> {r['err_after'] if r['err_after'] is not None else '-'}"
        lines.append(f"| {r['name']} | {', '.join(r['truth']) or 'none'} | {', '.join(r['named']) or 'adequate'} | "
                     f"{dev} | {err} | {r['seconds']} |")
    return "\n".join(lines)


def plot_power(summary: dict, path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(summary)
    cols = 3
    fig, axes = plt.subplots((n + cols - 1) // cols, cols, figsize=(11, 3.0 * ((n + cols - 1) // cols)))
    for ax, (e, s) in zip(np.ravel(axes), summary.items(), strict=False):
        ax.semilogx(s["strengths"], s["rates"], "o-")
        ax.axhline(0.5, color="grey", lw=0.5)
        if e in POWER and POWER[e][2] is not None:
            ax.axvline(POWER[e][2], color="C3", lw=0.8, ls="--", label="shared dataset")
            ax.legend(fontsize=7, loc="lower right")
        ax.set_ylim(-0.05, 1.05)
        ax.set_title(e, fontsize=9)
        ax.set_xlabel({"dead_time": "tau [s]", "wall_attenuation": "mu [1/m]", "anisotropy": "fraction",
                       "air_attenuation": "mu [1/m]", "second_source": "cps at 1 m",
                       "background_gradient": "|g| [cps/m]", "gain_drift": "%/min", "pose_drift": "|v| [m/s]",
                       "over_dispersion": "relative sd per frame", "unmapped_wall": "mu x thickness"
                       }.get(e, "cps at 1 m" if e.startswith("second_source") else "strength"), fontsize=8)
        ax.set_ylabel("detection rate", fontsize=8)
    for ax in np.ravel(axes)[n:]:
        ax.axis("off")
    fig.suptitle("radseek diagnose on an independent forward model: detection rate against strength", fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def report(rows: list[dict]) -> tuple[str, dict]:
    out = []
    kinds = {k: [r for r in rows if r["kind"] == k] for k in ("shared", "power", "null", "pairs")}
    if kinds["shared"]:
        out += ["### Shared datasets (regression set)", "", rows_table(kinds["shared"]), ""]
    summary: dict[str, Any] = {}
    if kinds["power"]:
        tab, summary = power_table(rows)
        out += ["### Power: detection rate against strength (independent forward model)", "", tab, ""]
    nulls = kinds["null"]
    if nulls:
        fa = [r for r in nulls if r["named"]]
        z = [(r["dev_before"] - r["dev_expected_before"]) / max(r["dev_sd_before"], 1e-9) for r in nulls]
        named = sorted({n for r in fa for n in r["named"]})
        out += ["### Null flights", "",
                f"- {len(fa)} false alarm(s) in {len(nulls)} null flights ({len(fa) / len(nulls):.1%}; target <= 2 %)"
                + (f": named {', '.join(named)} ({', '.join(r['name'] for r in fa)})" if fa else ""),
                f"- baseline deviance/dof sits {statistics.mean(z):+.2f} +- {statistics.pstdev(z):.2f} sd from its "
                "expected value", ""]
        summary["null"] = {"false_alarms": len(fa), "n": len(nulls)}
    if kinds["pairs"]:
        out += ["### Two missing effects", "", rows_table(kinds["pairs"]), ""]
    for kind, title, table in (("walls", "Unmapped walls: detection and location against mu x t", walls_table),
                               ("nuclides", "Second sources of other nuclides", nuclides_table),
                               ("conull", "Null flights with Co-60 and Cs-137 primaries", conull_table),
                               ("offlist", "Off-list physics: an honest open verdict", offlist_table)):
        if any(r["kind"] == kind for r in rows):
            tab, summary[kind] = table(rows)
            out += [f"### {title}", "", tab, ""]
    secs = [r["seconds"] for r in rows]
    if secs:
        cpu = [r.get("cpu_seconds", math.nan) for r in rows]
        out.append(f"Time per diagnose call: wall median {statistics.median(secs):.1f} s, max {max(secs):.1f} s; "
                   f"CPU median {statistics.median(cpu):.1f} s, max {max(cpu):.1f} s over {len(secs)} calls "
                   f"(slowest: {max(rows, key=lambda r: r['seconds'])['name']}).")
        summary["seconds"] = {"median": statistics.median(secs), "max": max(secs), "cpu_median": statistics.median(cpu),
                              "cpu_max": max(cpu)}
    return "\n".join(out) + "\n", summary


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--only", choices=SECTIONS, action="append")
    p.add_argument("--seeds", type=int, default=2, help="seeds per effect and strength (2)")
    p.add_argument("--nulls", type=int, default=60, help="null flights (60)")
    p.add_argument("--conulls", type=int, default=60, help="conull flights, half with a Co-60 primary (60)")
    p.add_argument("--starts", type=int, default=4, help="multi-starts of the baseline fit (4)")
    p.add_argument("--jobs", type=int, default=1, help="flights diagnosed in parallel (processes)")
    p.add_argument("--jsonl", type=Path, default=None, help="append one JSON row per flight here; rows already "
                   "there are not rerun (resume)")
    p.add_argument("--plot", type=Path, default=None, help="write the power curves here (PNG)")
    p.add_argument("--markdown", type=Path, default=None, help="also write the report here")
    p.add_argument("--limit", type=int, default=None, help="run at most this many flights (a smoke test)")
    p.add_argument("--names", nargs="+", default=None, help="only flights whose name starts with one of these")
    args = p.parse_args(argv)
    todo = jobs(args.only or list(SECTIONS), args.seeds, args.nulls, args.conulls)
    if args.names:
        todo = [j for j in todo if any(j["name"].startswith(n) for n in args.names)]
    if args.limit:
        todo = todo[: args.limit]
    rows: list[dict] = []
    if args.jsonl and args.jsonl.exists():
        done = {json.loads(line)["name"]: json.loads(line) for line in args.jsonl.read_text().splitlines() if line}
        rows = [done[j["name"]] for j in todo if j["name"] in done]
        todo = [j for j in todo if j["name"] not in done]

    def keep(r: dict) -> None:
        rows.append(r)
        print(f"[{len(rows)}] {r['name']}: truth {r['truth']} named {r['named']} ({r['seconds']} s)", file=sys.stderr,
              flush=True)
        if args.jsonl:
            with args.jsonl.open("a") as fh:
                fh.write(json.dumps(r) + "\n")

    if args.jobs > 1:
        with ProcessPoolExecutor(args.jobs) as ex:
            for r in ex.map(run_one, todo, [args.starts] * len(todo)):
                keep(r)
    else:
        for j in todo:
            keep(run_one(j, args.starts))
    text, summary = report(rows)
    print(text)
    curves = open_world_curves(rows)
    if args.plot and (curves or any(r["kind"] == "power" for r in rows)):
        plot_power({**power_table(rows)[1], **curves}, args.plot)
    if args.markdown:
        args.markdown.write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
