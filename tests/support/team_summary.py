"""A team member's mission_summary.json as `radseek mission` writes it for the vehicle that decided: the report
tests build team runs from shared datasets and need one found estimate."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np


def write_found_summary(folder: Path, x: float = 4.3, y: float = 3.7) -> None:
    """``folder``/mission_summary.json: a converged estimate at (x, y), 0.1 m 1-sigma per axis, 80 s."""
    cov = np.diag([0.01, 0.01, 0.0, 100.0]).tolist()
    (folder / "mission_summary.json").write_text(json.dumps({
        "estimate": {"x": x, "y": y, "covariance": cov, "sigma_m": 0.14}, "reason": "converged",
        "mission_time_s": 80.0}))
