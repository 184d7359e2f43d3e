"""Bremsstrahlung of a source's own betas, stopped in the source's matrix (a uranium glaze, a thorium rod): a photon
continuum the line tables do not have. Its shape comes from the members' ICRP-107 beta spectra (pydecay) and
Kramers' thick-target law, a stopping electron of kinetic energy T giving dN/dk proportional to (T - k) / k photons
per unit photon energy k < T (Kramers 1923; Evans, The Atomic Nucleus, ch. 21); its size depends on the matrix's
atomic number and the source's build, so it is a source amplitude, fitted like the activity.

``spectra.model`` reads a source named ``brems:NAME`` (e.g. ``brems:U-nat``, ``brems:Th-232@5y``) through
:func:`lines`; the members' decays per decay of the source are ``radseek.photon_lines.source_members``.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import pydecay
from pydecay.nuclide import Nuclide

from radseek.photon_lines import source_members

PREFIX = "brems:"
STEP_KEV = 20.0
MIN_KEV = 30.0


@lru_cache(maxsize=16)
def lines(name: str) -> tuple[tuple[float, float], ...]:
    """(photon energy keV, relative photons) of the thick-target bremsstrahlung of ``name``'s betas, on a
    ``STEP_KEV`` grid from ``MIN_KEV``; normalised to 1 photon in all (its size is fitted)."""
    k = np.arange(MIN_KEV, 3000.0, STEP_KEV) + STEP_KEV / 2
    total = np.zeros_like(k)
    for nuc, w in source_members(name).items():
        beta = sum(m.branch for m in Nuclide.load(nuc).decay_modes if m.mode == "B-")
        if beta <= 0:  # an alpha emitter (ICRP-107 lists U-238's fission-fragment betas, 1e-6 of its decays)
            continue
        try:
            e_mev, amp = pydecay.beta_spectrum(nuc)
        except Exception:  # no beta branch in the catalog (alpha emitters): no bremsstrahlung from it
            continue
        t = np.asarray(e_mev, dtype=float) * 1000.0
        a = np.asarray(amp, dtype=float)
        if len(t) < 2 or a.sum() <= 0:
            continue
        dt = np.gradient(t)
        p = beta * a * dt / (a * dt).sum()  # electrons per bin, per decay of this member
        # Kramers: photons per unit k from an electron of kinetic energy T: (T - k)/k for k < T
        per = np.clip(t[None, :] - k[:, None], 0.0, None) / k[:, None]
        total += w * (per * p[None, :]).sum(1)
    if total.sum() <= 0:
        raise ValueError(f"{name!r}: no beta emitter among its members, so no bremsstrahlung")
    keep = total > 1e-9 * total.max()
    y = total[keep] / total[keep].sum()
    return tuple((float(e), float(v)) for e, v in zip(k[keep], y, strict=True))
