"""The calibrated detector file (``radseek calibrate --out DET.json``): a real crystal's response, as data.

It is a contract between the calibration tool, the emulator (a scene's ``detector = "DET.json"``) and the
estimator's spectral model, which must not import the simulator: so the file carries both the fitted physical
parameters (for the emulator to rebuild the response from physics) and, per nuclide, the resulting measured-energy
spectrum as a cumulative table (for the estimator to use as its source template).

JSON layout (``format`` = ``radseek-detector/1``)::

    {"format": "radseek-detector/1", "name": "RC-102-001272", "material": "CsI(Tl)",
     "parameters": {"fwhm_at_662": 0.102, "fwhm_exponent": 0.44, "crystal_mm": 10.0, ...},
     "errors": {"fwhm_at_662": 0.0008, ...},           # 1 sigma (HESSE), fitted parameters only
     "effects": ["resolution_law", ...],              # what forward selection added to the emulator's response
     "missing": [...],                                # what is still wrong (energy windows, not identifiable)
     "calibrated_on": {"spectrum": "...", "nuclides": ["Cs-137"], "background": "...", "live_time_s": 300},
     "fit": {"deviance_per_dof": 1.6, "total_variation_32": 0.028, "total_variation_native": 0.04},
     "templates": {"grid_keV": [0, 4, ...], "cdf": {"Cs-137": [...], ...}}}   # deposited-energy cumulative, 0..1

Parameter names and meanings are those of ``spectra.model.PARAMS`` (units in the name where there is one).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

FORMAT = "radseek-detector/1"
#: parameters the emulator uses (the rest describe the measuring device's own calibration and electronics)
PHYSICAL = ("fwhm_at_662", "fwhm_exponent", "crystal_mm", "escape_scale", "backscatter_fraction", "scatter_side",
            "scatter_multiple", "absorber_g_cm2", "k_escape")


class DetectorFileError(ValueError):
    """A detector file that breaks the format; the message names the file and the field."""


@dataclass
class DetectorFile:
    name: str
    parameters: dict[str, float]
    errors: dict[str, float] = field(default_factory=dict)
    effects: list[str] = field(default_factory=list)
    missing: list[Any] = field(default_factory=list)
    calibrated_on: dict[str, Any] = field(default_factory=dict)
    fit: dict[str, Any] = field(default_factory=dict)
    grid_keV: np.ndarray | None = None
    cdf: dict[str, np.ndarray] = field(default_factory=dict)
    material: str = "CsI(Tl)"

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"format": FORMAT, "name": self.name, "material": self.material,
                               "parameters": {k: float(v) for k, v in self.parameters.items()},
                               "errors": {k: float(v) for k, v in self.errors.items()},
                               "effects": list(self.effects), "missing": list(self.missing),
                               "calibrated_on": self.calibrated_on, "fit": self.fit}
        if self.grid_keV is not None:
            out["templates"] = {"grid_keV": [round(float(x), 4) for x in self.grid_keV],
                                "cdf": {k: [round(float(x), 7) for x in v] for k, v in self.cdf.items()}}
        return out

    def write(self, path: str | Path) -> Path:
        """Write the file atomically; a NaN or infinity anywhere is refused (``DetectorFileError`` naming the field):
        strict JSON, and a reader would reject it anyway."""
        from radseek_io.outdir import atomic_write_text

        data = self.to_json()
        bad = first_non_finite(data)
        if bad is not None:
            raise DetectorFileError(f"{path}: not written: field '{bad[0]}' is {bad[1]!r} (a detector file holds "
                                    "finite numbers only)")
        p = Path(path)
        atomic_write_text(p, json.dumps(data, indent=1, allow_nan=False) + "\n")
        return p

    def template(self, nuclide: str) -> tuple[np.ndarray, np.ndarray]:
        """(grid keV, cumulative 0..1) of the measured-energy spectrum of ``nuclide``; KeyError names the known."""
        if self.grid_keV is None or nuclide not in self.cdf:
            raise KeyError(f"detector file {self.name!r} has no template for {nuclide!r} "
                           f"(has: {', '.join(sorted(self.cdf)) or 'none'})")
        return self.grid_keV, self.cdf[nuclide]

    def channel_fractions(self, nuclide: str, edges_keV: np.ndarray) -> np.ndarray:
        """Share of the counts above edges[0] in each channel [edges_k, edges_k+1); the last is open above."""
        grid, cdf = self.template(nuclide)
        c = np.interp(np.asarray(edges_keV, dtype=float), grid, cdf)
        frac = np.diff(c)
        frac[-1] = cdf[-1] - c[-2]
        return frac / max(frac.sum(), 1e-300)


def first_non_finite(obj: Any, where: str = "") -> tuple[str, float] | None:
    """(field path, value) of the first NaN or infinity in a JSON-like structure, or None."""
    if isinstance(obj, float | np.floating):
        return None if math.isfinite(float(obj)) else (where or "<value>", float(obj))
    if isinstance(obj, dict):
        keys = ((f"{where}.{k}" if where else str(k), v) for k, v in obj.items())
    elif isinstance(obj, list | tuple | np.ndarray):
        keys = ((f"{where}[{i}]", v) for i, v in enumerate(obj))
    else:
        return None
    for key, v in keys:
        hit = first_non_finite(v, key)
        if hit is not None:
            return hit
    return None


def _num(origin: str, where: str, v: Any) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(float(v)):
        raise DetectorFileError(f"{origin}: field '{where}': must be a finite number (got {v!r})")
    return float(v)


def from_json(data: Any, origin: str = "<detector>") -> DetectorFile:
    if not isinstance(data, dict):
        raise DetectorFileError(f"{origin}: a detector file must be a JSON object, got {type(data).__name__}")
    if data.get("format") != FORMAT:
        raise DetectorFileError(f"{origin}: field 'format': must be {FORMAT!r} (got {data.get('format')!r})")
    params = data.get("parameters")
    if not isinstance(params, dict) or not params:
        raise DetectorFileError(f"{origin}: field 'parameters': must be a non-empty object")
    parameters = {k: _num(origin, f"parameters.{k}", v) for k, v in params.items()}
    for k in PHYSICAL:
        if k not in parameters:
            raise DetectorFileError(f"{origin}: field 'parameters.{k}': missing")
    if not 0 < parameters["fwhm_at_662"] < 1:
        raise DetectorFileError(f"{origin}: field 'parameters.fwhm_at_662': must be in (0, 1)")
    if parameters["crystal_mm"] <= 0:
        raise DetectorFileError(f"{origin}: field 'parameters.crystal_mm': must be > 0")
    errors = {k: _num(origin, f"errors.{k}", v) for k, v in (data.get("errors") or {}).items()}
    grid = None
    cdf: dict[str, np.ndarray] = {}
    t = data.get("templates")
    if t is not None:
        if not isinstance(t, dict) or not isinstance(t.get("grid_keV"), list) or not isinstance(t.get("cdf"), dict):
            raise DetectorFileError(f"{origin}: field 'templates': needs 'grid_keV' (list) and 'cdf' (object)")
        grid = np.array([_num(origin, "templates.grid_keV", x) for x in t["grid_keV"]])
        if len(grid) < 2 or np.any(np.diff(grid) <= 0):
            raise DetectorFileError(f"{origin}: field 'templates.grid_keV': must be ascending")
        for nuc, vals in t["cdf"].items():
            if not isinstance(vals, list) or len(vals) != len(grid):
                raise DetectorFileError(f"{origin}: field 'templates.cdf.{nuc}': needs {len(grid)} values")
            arr = np.array([_num(origin, f"templates.cdf.{nuc}", x) for x in vals])
            if np.any(np.diff(arr) < -1e-9):
                raise DetectorFileError(f"{origin}: field 'templates.cdf.{nuc}': must be non-decreasing")
            cdf[nuc] = arr
    return DetectorFile(str(data.get("name", "detector")), parameters, errors, list(data.get("effects") or []),
                        list(data.get("missing") or []), dict(data.get("calibrated_on") or {}),
                        dict(data.get("fit") or {}), grid, cdf, str(data.get("material", "CsI(Tl)")))


def read_detector_file(path: str | Path) -> DetectorFile:
    p = Path(path)
    try:
        text = p.read_text()
    except FileNotFoundError:
        raise DetectorFileError(f"{p}: detector file not found") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise DetectorFileError(f"{p}: not valid JSON: {exc}") from None
    return from_json(data, str(p))
