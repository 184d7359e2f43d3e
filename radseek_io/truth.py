"""truth.json, the simulated truth of a dataset: read and validated for the tools that score a search.

Only the simulator, the launchers, the benchmarks, the tests and the command-line tools' error reports
read it; the flight software (``mission``, ``estimator``, ``planner``) never imports this module
(tests/test_architecture.py). Written by :func:`radseek_io.dataset.write_dataset`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path

from radseek.dataset import EFFECTS, Dataset
from radseek.truth import Truth, TruthSource
from radseek_io.dataset import _err, _load_json, _number, read_dataset


def read_truth(file: Path) -> Truth | None:
    """Read truth.json (None when absent): sources and effects with finite numbers; errors name the key."""
    file = Path(file)
    d = _load_json(file, required=False)
    if d is None and not file.exists():
        return None
    if not isinstance(d, dict):
        raise _err(file, f"must hold a JSON object, got {type(d).__name__}")
    raw_sources = d.get("sources", [])
    if not isinstance(raw_sources, list):
        raise _err(file, f"key 'sources' must be a list, got {raw_sources!r}")
    sources = []
    for i, s in enumerate(raw_sources):
        where = f"sources[{i}]"
        if not isinstance(s, dict):
            raise _err(file, f"{where} must be an object, got {s!r}")
        for key in ("x", "y", "cps_at_1m"):
            if key not in s:
                raise _err(file, f"{where}: missing key {key!r}")
        x, y = _number(s["x"], f"{where}.x", file), _number(s["y"], f"{where}.y", file)
        z = _number(s.get("z", 0.0), f"{where}.z", file)
        cps = _number(s["cps_at_1m"], f"{where}.cps_at_1m", file)
        if cps < 0:
            raise _err(file, f"key '{where}.cps_at_1m' must be >= 0, got {cps}")
        nuclide = s.get("nuclide", "Cs-137")
        if not isinstance(nuclide, str):
            raise _err(file, f"key '{where}.nuclide' must be a string, got {nuclide!r}")
        sources.append(TruthSource(x, y, z, cps, nuclide))
    effects = d.get("effects", {}) or {}
    if not isinstance(effects, dict):
        raise _err(file, f"key 'effects' must be an object, got {effects!r}")
    for name, params in effects.items():
        if not isinstance(params, dict):
            raise _err(file, f"key 'effects.{name}' must be an object of parameters, got {params!r}")
        for key in EFFECTS.get(name, ()):  # unknown effects and extra parameters are kept as written
            if key in params or (name == "second_source" and key != "z"):
                if key not in params:
                    raise _err(file, f"key 'effects.{name}': missing parameter {key!r}")
                _number(params[key], f"effects.{name}.{key}", file)
    if "second_source" in effects and not sources:
        raise _err(file, "key 'effects.second_source' needs a primary source in 'sources'")
    background = _number(d["background_cps"], "background_cps", file) if "background_cps" in d else float("nan")
    return Truth(tuple(sources), background, effects)


def read_dataset_with_truth(path: str | Path, progress: Callable[[int, int], None] | None = None,
                            truncated_last_row: str = "skip") -> Dataset:
    """:func:`radseek_io.dataset.read_dataset` plus the directory's ``truth.json`` (``truth`` None when absent)."""
    ds = read_dataset(path, progress=progress, truncated_last_row=truncated_last_row)
    return dataclasses.replace(ds, truth=read_truth(ds.path / "truth.json"))
