"""Photons of the source backscattered once by material around it (a bench, a wall, a box behind the source): a
property of one measurement's set-up, not of the detector, so it is a per-spectrum nuisance with its own amplitude
and is never written to a detector file.

Each line of energy E is Compton-scattered through 110-180 deg (the response's backscatter angles,
``detector_fw_sim.response.backscatter_energies``): energies E' = E / (1 + (E / m_e c^2)(1 - cos theta)) with
Klein-Nishina weights dsigma/dOmega sin(theta), and the line's share scaled by the thick-scatterer yield relative to
662 keV (``response.scatter_share_scale``, the law the calibrated backscatter share follows). The lines' 180 deg
energies pile up at 184-250 keV for 0.3-2.6 MeV lines: a backscatter peak that a source nearer a scatterer than
the calibration sources shows above the unit's calibrated backscatter share.

``spectra.model`` reads a source named ``backscatter:NAME`` (e.g. ``backscatter:Ra-226``) through :func:`lines`;
evaluate it with the room's scatter shares at zero (:func:`component_params`): those photons reach the crystal
after their one scatter.
"""

from __future__ import annotations

from functools import lru_cache

from detector_fw_sim import response
from radseek.photon_lines import source_lines

PREFIX = "backscatter:"
#: angle nodes per line (Klein-Nishina weights over 110-180 deg)
N_ANGLES = 24
#: the scattered photons are gathered in bins of this width (keV, at their mean energy): far below the crystal's
#: FWHM at 100-300 keV (20-30 keV), and it keeps the number of photon energies the response follows small
STEP_KEV = 2.0


@lru_cache(maxsize=16)
def lines(name: str) -> tuple[tuple[float, float], ...]:
    """(photon energy keV, relative photons) of ``name``'s lines backscattered once through 110-180 deg,
    normalised to 1 photon in all (its size is the measurement's, fitted)."""
    sums: dict[int, list[float]] = {}  # STEP_KEV bin -> [photons, photons x energy]
    for e, y in source_lines(name):
        scale = response.scatter_share_scale(float(e), response.BACKSCATTER_MIN_DEG, 180.0)
        energies, weights = response.backscatter_energies(float(e), N_ANGLES)
        for ep, w in zip(energies, weights, strict=True):
            acc = sums.setdefault(int(ep // STEP_KEV), [0.0, 0.0])
            acc[0] += y * scale * float(w)
            acc[1] += y * scale * float(w) * float(ep)
    total = sum(a[0] for a in sums.values())
    if total <= 0:
        raise ValueError(f"{name!r}: no photon lines to backscatter")
    return tuple((a[1] / a[0], a[0] / total) for _, a in sorted(sums.items()) if a[0] > 0)


def component_params(params: dict[str, float]) -> dict[str, float]:
    """The response's parameters for the backscattered photons: the crystal, resolution, energy law, electron escape
    and pile-up as fitted, the room's scatter shares at zero (these photons have had their scatter)."""
    return dict(params, backscatter_fraction=0.0, scatter_side=0.0, scatter_multiple=0.0)
