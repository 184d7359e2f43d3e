"""The simulated truth (truth.json): where the sources really are and which effects the world has.

For the simulator that draws it, the launchers and benchmarks that score a search, and the error reports of
the command-line tools: the flight software (``mission``, ``estimator``, ``planner``) never imports this
module (tests/test_architecture.py). Read and written by :mod:`radseek_io.truth`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True)
class TruthSource:
    x: float
    y: float
    z: float
    cps_at_1m: float
    nuclide: str = "Cs-137"

    @property
    def position(self) -> np.ndarray:
        return np.array([self.x, self.y, self.z])


@dataclass(frozen=True)
class Truth:
    """The simulated truth (truth.json): for tests and error reports only, never for estimators."""

    sources: tuple[TruthSource, ...]
    background_cps: float
    effects: dict[str, dict[str, float]]

    def all_sources(self) -> tuple[TruthSource, ...]:
        """The primary sources plus a ``second_source`` effect's source, if any."""
        extra = self.effects.get("second_source")
        if not extra:
            return self.sources
        s = TruthSource(extra["x"], extra["y"], extra.get("z", 0.0), extra["cps_at_1m"], self.sources[0].nuclide)
        return (*self.sources, s)

    def to_dict(self) -> dict[str, Any]:
        return {
            "sources": [
                {"x": s.x, "y": s.y, "z": s.z, "cps_at_1m": s.cps_at_1m, "nuclide": s.nuclide} for s in self.sources
            ],
            "background_cps": self.background_cps,
            "effects": self.effects,
        }
