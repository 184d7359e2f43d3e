"""Bremsstrahlung of a source's own betas, stopped in the source's matrix (a uranium glaze, a thorium rod): a photon
continuum the line tables do not have. Its shape comes from the members' ICRP-107 beta spectra (pydecay) and
Kramers' thick-target law, a stopping electron of kinetic energy T giving dN/dk proportional to (T - k) / k photons
per unit photon energy k < T (Kramers 1923; Evans, The Atomic Nucleus, ch. 21); its size depends on the matrix's
atomic number and the source's build, so it is a source amplitude, fitted like the activity.

``spectra.model`` reads a source named ``brems:NAME`` (e.g. ``brems:U-nat``) through :func:`lines`.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import pydecay
from pydecay.nuclide import Nuclide

from radseek.photon_lines import CHAIN_MIN_BRANCH, FRESH_URANIUM, NATURAL_CHAINS, natural_uranium_activity_ratio

PREFIX = "brems:"
STEP_KEV = 20.0
MIN_KEV = 30.0


def _members(name: str) -> dict[str, float]:
    """Decays of each member per decay of the source (the same walks as ``radseek.photon_lines.source_lines``)."""
    out: dict[str, float] = {}

    def walk(nuc: str, w: float, follow, depth: int) -> None:
        out[nuc] = out.get(nuc, 0.0) + w
        if depth > 40:
            return
        n = Nuclide.load(nuc)
        if n.is_stable:
            return
        for d, b in zip(n.progeny, n.branching, strict=False):
            try:
                dn = Nuclide.load(d)
            except Exception:  # pydecay's own errors: no progeny to follow
                continue
            if not dn.is_stable and follow(n, dn, w * float(b)):
                walk(d, w * float(b), follow, depth + 1)

    def short(head: str):
        t = Nuclide.load(head).half_life_s
        return lambda _p, d, _w: d.half_life_s < 1e-3 * t and d.half_life_s < 30 * 86400

    if name == FRESH_URANIUM:
        for head, w in (("U-238", 1.0), ("U-234", 1.0), ("U-235", natural_uranium_activity_ratio())):
            walk(head, w, short(head), 0)
    elif name in NATURAL_CHAINS:
        walk(name, 1.0, lambda _p, _d, w: w >= CHAIN_MIN_BRANCH, 0)
    else:
        walk(name, 1.0, short(name), 0)
    return out


@lru_cache(maxsize=16)
def lines(name: str) -> tuple[tuple[float, float], ...]:
    """(photon energy keV, relative photons) of the thick-target bremsstrahlung of ``name``'s betas, on a
    ``STEP_KEV`` grid from ``MIN_KEV``; normalised to 1 photon in all (its size is fitted)."""
    k = np.arange(MIN_KEV, 3000.0, STEP_KEV) + STEP_KEV / 2
    total = np.zeros_like(k)
    for nuc, w in _members(name).items():
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
