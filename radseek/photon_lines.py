"""Photon lines of a nuclide and of the progeny its decay chain reaches, from pydecay's ICRP-107 tables (never typed
here): shared by the emulator's detector response (``detector_fw_sim.response``), the calibrated spectral model
(``spectra``) and the flight software's nuclide test (``estimator.diagnose.nuclide``).
"""

from __future__ import annotations

import re
from collections.abc import Callable
from functools import cache, lru_cache
from pathlib import Path
from typing import Any

import pydecay.data
from pydecay.data import load_catalog, load_rad_for
from pydecay.exceptions import NuclideNotFoundError
from pydecay.nuclide import Nuclide, normalize_nuclide_name

from radseek import machine_cache

MIN_LINE_KEV = 10.0  # lines below this never reach a 40 keV threshold
MIN_LINE_YIELD = 1e-3


@cache
def _nuclide(name: str) -> Nuclide:
    """``Nuclide.load(name)`` from pydecay's cached catalog, once per name and process: ``Nuclide.load`` parses the
    whole ICRP-107 table (0.9 MB of JSON, ~45 ms) on every call, and one scene's validation made ~20 such calls.
    Raises pydecay's NuclideNotFoundError / DataFormatError as ``Nuclide.load`` does (errors are not cached)."""
    norm = normalize_nuclide_name(name)
    records = load_catalog()
    if norm not in records:
        raise NuclideNotFoundError(f"nuclide {norm!r} not found in ICRP-107 catalog")
    return Nuclide.from_record(norm, records[norm])


@cache
def _emissions(name: str) -> tuple[dict[str, Any], ...]:
    """``pydecay.emissions(name)`` (its RAD rows of a known nuclide) without its uncached ``Nuclide.load``, once per
    name and process; () when pydecay has none or does not know the name. The rows come from this machine's
    :func:`rows_cache` when it holds them: pydecay's ``load_rad_for`` parses the whole 37 MB RAD table (0.6 s of
    CPU) for the handful of nuclides a scene names, in every process that loads a scene or a detector response."""
    try:
        norm = _nuclide(name).name
    except Exception:  # pydecay raises its own NuclideNotFoundError / DataFormatError
        return ()
    cached = _read_rows(norm)
    if cached is not None:
        return cached
    try:
        rows = tuple(load_rad_for(name))
    except Exception:  # pydecay's own errors: a known nuclide without RAD rows
        rows = ()
    _store_rows(norm, rows)
    return rows


# ---- this machine's cache of pydecay's RAD rows (radseek.machine_cache)
#
# A folder per pydecay installation (its version, and the RAD file's path, size and modification time), holding one
# JSON file per nuclide a process on this machine has asked for: pydecay's rows as it gives them.

#: the cache folder's variable (radseek.machine_cache)
CACHE_ENV = machine_cache.CACHE_ENV


def _rad_file() -> Path:
    return Path(pydecay.data.__file__).with_name("icrp107_rad.json.gz")


def rows_cache() -> Path | None:
    """The folder caching pydecay's RAD rows on this machine (None when pydecay's table cannot be stat'ed)."""
    return machine_cache.keyed_path("pydecay-rad-rows", getattr(pydecay, "__version__", "?"), _rad_file())


_SAFE_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9-]*")


def _row_file(name: str) -> Path | None:
    folder = rows_cache()
    if folder is None or not _SAFE_NAME.fullmatch(name):
        return None
    return folder / f"{name}.json"


def _read_rows(name: str) -> tuple[dict[str, Any], ...] | None:
    """``name``'s cached rows; None when the cache has none, or none it can read."""
    rows = machine_cache.read_json(_row_file(name))
    if not (isinstance(rows, list) and all(isinstance(r, dict) for r in rows)):
        return None
    return tuple(rows)


def _store_rows(name: str, rows: tuple[dict[str, Any], ...]) -> None:
    """Cache ``name``'s rows (atomically; an OSError leaves the cache as it was)."""
    machine_cache.write_json(_row_file(name), list(rows))


def add_photon_lines(lines: dict[float, float], nuclide: str, weight: float) -> None:
    """Add ``weight`` x the photons per decay of ``nuclide`` (pydecay's ICRP-107 emissions, >= ``MIN_LINE_KEV``)
    to ``lines`` (energy keV rounded to 1 eV -> photons); a nuclide pydecay has no emissions for adds none."""
    for r in _emissions(nuclide):
        if r.get("is_photon") and r["E_MeV"] * 1000.0 >= MIN_LINE_KEV:
            e = round(r["E_MeV"] * 1000.0, 3)
            lines[e] = lines.get(e, 0.0) + weight * float(r["prob"])


def chain_photon_lines(head: str, follow: Callable[[Any, float], bool], max_depth: int) -> dict[float, float]:
    """Photons per decay of ``head`` (energy keV -> photons, :func:`add_photon_lines`) with those of the
    progeny its decay chain reaches: a radioactive daughter is walked, weighted by pydecay's branching
    ratios, when ``follow(daughter Nuclide, weight)`` says so, down to ``max_depth`` generations."""
    lines: dict[float, float] = {}

    def walk(name: str, weight: float, depth: int) -> None:
        add_photon_lines(lines, name, weight)
        if depth > max_depth:
            return
        try:
            nuc = _nuclide(name)
        except Exception:  # pydecay's own errors: a name it cannot load has no progeny to follow
            return
        if nuc.is_stable:
            return
        for daughter, branch in zip(nuc.progeny, nuc.branching, strict=False):
            try:
                d = _nuclide(daughter)
            except Exception:
                continue
            w = weight * float(branch)
            if not d.is_stable and follow(d, w):
                walk(daughter, w, depth + 1)

    walk(head, 1.0, 0)
    return lines


@lru_cache(maxsize=64)
def gamma_lines(nuclide: str, min_yield: float = MIN_LINE_YIELD) -> tuple[tuple[float, float], ...]:
    """(energy keV, photons per decay of ``nuclide``) from pydecay's ICRP-107 tables.

    Daughters much shorter-lived than the parent (secular equilibrium, e.g. Ba-137m under Cs-137)
    contribute with their branching ratio. Raises ``ValueError`` naming an unknown nuclide.
    """
    try:
        parent = _nuclide(nuclide)
    except Exception as exc:  # pydecay raises its own NuclideNotFoundError / DataFormatError
        raise ValueError(f"unknown nuclide {nuclide!r} ({exc})") from None
    lines = chain_photon_lines(
        parent.name, max_depth=3,
        follow=lambda d, _w: d.half_life_s < 1e-3 * parent.half_life_s and d.half_life_s < 30 * 86400)
    out = tuple(sorted((e, y) for e, y in lines.items() if y >= min_yield))
    if not out:
        raise ValueError(f"nuclide {nuclide!r} emits no gamma line above {MIN_LINE_KEV} keV in pydecay's tables")
    return out




#: heads of the natural decay series. As a calibration source (``radseek calibrate X=Th-232``) the name means the head
#: with its whole chain in secular equilibrium, as in thorium lantern mantles and welding rods, radium dials, ore and
#: old uranium glaze: every member decays at the head's rate times its branching. (K-40 has no radioactive progeny:
#: ``gamma_lines("K-40")`` is already its whole emission.)
NATURAL_CHAINS = ("Th-232", "U-238", "U-235", "Ra-226")
#: a branch carrying less than this share of the head's decays is not walked further (U-238's At-218, Rn-218 ...)
CHAIN_MIN_BRANCH = 1e-6


@lru_cache(maxsize=16)
def equilibrium_lines(head: str, min_yield: float = MIN_LINE_YIELD) -> tuple[tuple[float, float], ...]:
    """(energy keV, photons per decay of ``head``) of ``head`` and its whole decay chain in secular equilibrium.

    The chain is walked to its stable end with pydecay's branching ratios (every member, however long-lived, decays
    at the head's rate times the product of the branchings above it); energies and intensities are pydecay's
    ICRP-107 (ENSDF-based) emissions. Th-232 gives Tl-208's 2614.5 keV line at 0.3594 x its own 0.99 intensity.
    """
    try:
        _nuclide(head)
    except Exception as exc:  # pydecay raises its own NuclideNotFoundError / DataFormatError
        raise ValueError(f"unknown nuclide {head!r} ({exc})") from None
    lines = chain_photon_lines(head, max_depth=40, follow=lambda _d, w: w >= CHAIN_MIN_BRANCH)
    return tuple(sorted((e, y) for e, y in lines.items() if y >= min_yield))


#: natural uranium separated from its daughters (``radseek calibrate glass.xml=U-nat``): uranium glass and glaze,
#: yellowcake. Chemistry keeps the uranium isotopes and removes thorium and radium; within months Th-234 and Pa-234m
#: grow back to U-238's activity, and Th-231 to U-235's, while Th-230 (75,000 y) holds Ra-226 and its lines back for
#: millennia. U-234 is uranium and stays at U-238's activity.
FRESH_URANIUM = "U-nat"
#: atom ratio U-235 / U-238 of natural uranium: 0.007204 / 0.992742, CIAAW / IUPAC isotopic abundances (Meija et
#: al., Pure Appl. Chem. 88 (2016) 293); the activity ratio follows with pydecay's half-lives (0.0461)
NATURAL_U235_U238_ATOMS = 0.007204 / 0.992742


def natural_uranium_activity_ratio() -> float:
    """Activity of U-235 per U-238 decay in natural uranium: the atom ratio times T(U-238) / T(U-235)."""
    t238 = _nuclide("U-238").half_life_s
    t235 = _nuclide("U-235").half_life_s
    return NATURAL_U235_U238_ATOMS * t238 / t235


@lru_cache(maxsize=4)
def fresh_uranium_lines(min_yield: float = MIN_LINE_YIELD) -> tuple[tuple[float, float], ...]:
    """(energy keV, photons per U-238 decay) of ``FRESH_URANIUM``: U-238 with Th-234 and Pa-234m, U-234 at the same
    activity, U-235 with Th-231 at the natural activity ratio; ICRP-107 emissions through pydecay."""
    lines: dict[float, float] = {}
    for name, w in (("U-238", 1.0), ("U-234", 1.0), ("U-235", natural_uranium_activity_ratio())):
        for e, y in gamma_lines(name, min_yield=0.0):
            lines[e] = lines.get(e, 0.0) + w * y
    return tuple(sorted((e, y) for e, y in lines.items() if y >= min_yield))


def source_lines(name: str) -> tuple[tuple[float, float], ...]:
    """Photon lines of a calibration source: a natural chain head (``NATURAL_CHAINS``) in secular equilibrium,
    ``FRESH_URANIUM`` (natural uranium without its daughters), any other nuclide with its short-lived progeny
    (``gamma_lines``)."""
    if name == FRESH_URANIUM:
        return fresh_uranium_lines()
    return equilibrium_lines(name) if name in NATURAL_CHAINS else gamma_lines(name)
