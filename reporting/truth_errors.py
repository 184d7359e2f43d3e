"""Errors of estimates against the simulated truth (``localize``, ``replay`` and ``diagnose`` print them when the
dataset has a truth): computed here, after the flight software has estimated without the truth."""

from __future__ import annotations

import numpy as np

from estimator.diagnose.runner import Diagnosis
from radseek.truth import Truth


def match_errors(sources: list[dict[str, float]], truth: Truth) -> list[dict[str, float]]:
    """Per true source (primary first): the nearest estimate's horizontal and 3-D position error and
    relative intensity error. Each estimate is used at most once (greedy by distance)."""
    true = list(truth.all_sources())
    est = [np.array([s["x"], s["y"], s["z"]]) for s in sources]
    pairs = sorted(((float(np.linalg.norm(e - t.position)), i, j) for j, t in enumerate(true)
                    for i, e in enumerate(est)))
    used_i: set[int] = set()
    used_j: set[int] = set()
    out: dict[int, dict[str, float]] = {}
    for d, i, j in pairs:
        if i in used_i or j in used_j:
            continue
        used_i.add(i)
        used_j.add(j)
        t, s = true[j], sources[i]
        out[j] = {"true_x": t.x, "true_y": t.y, "true_cps_at_1m": t.cps_at_1m,
                  "position_error_m": float(np.hypot(s["x"] - t.x, s["y"] - t.y)), "position_error_3d_m": d,
                  "intensity_error_rel": float(s["cps_at_1m"] / t.cps_at_1m - 1.0), "estimate": i}
    for j, t in enumerate(true):
        out.setdefault(j, {"true_x": t.x, "true_y": t.y, "true_cps_at_1m": t.cps_at_1m, "position_error_m": None,
                           "position_error_3d_m": None, "intensity_error_rel": None, "estimate": None})
    return [out[j] for j in range(len(true))]


def source_error(sources: list[dict[str, float]], truth: Truth | None) -> float | None:
    """3-D distance from the fitted primary source to the nearest true source (reporting only)."""
    if truth is None or not truth.sources:
        return None
    p = np.array([sources[0]["x"], sources[0]["y"], sources[0]["z"]])
    return float(min(np.linalg.norm(p - s.position) for s in truth.all_sources()))


def score_diagnosis(d: Diagnosis, truth: Truth | None) -> Diagnosis:
    """Fill each fitted model's ``source_error_m`` (None without a truth) and return ``d``."""
    for rep in {id(r): r for r in (d.current, d.after, d.final_report) if r is not None}.values():
        rep.source_error_m = source_error(rep.sources, truth)
    return d
