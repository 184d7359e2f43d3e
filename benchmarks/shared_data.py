"""Where the workplace's shared reference data lives: ``$RADSEEK_SHARED`` if set, else ``shared/`` beside the
repository (the layout the README's clone instructions give). The tests and benchmarks find the reference
datasets, real spectra and MAVSDK-Python examples through this one path, so a clone elsewhere needs only the
variable."""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["SHARED", "shared_path"]

SHARED = Path(os.environ.get("RADSEEK_SHARED") or Path(__file__).resolve().parents[2] / "shared")


def shared_path(*parts: str) -> Path:
    """A path under the shared folder, e.g. ``shared_path("datasets", "lattice-clean")``."""
    return SHARED.joinpath(*parts)
