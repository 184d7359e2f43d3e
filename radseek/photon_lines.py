"""Photon lines of a nuclide and of the progeny its decay chain reaches, from pydecay's ICRP-107 tables (never typed
here): shared by the emulator's detector response (``detector_fw_sim.response``), the calibrated spectral model
(``spectra``) and the flight software's nuclide test (``estimator.diagnose.nuclide``).
"""

from __future__ import annotations

import re
from collections.abc import Callable
from functools import cache, lru_cache
from pathlib import Path
from typing import TYPE_CHECKING, Any

from radseek import machine_cache

if TYPE_CHECKING:
    from pydecay import Inventory
    from pydecay.nuclide import Nuclide

# pydecay is imported where its tables are read, not here: the import costs a process 0.3 s of CPU (pint's unit
# registry, scipy.linalg), and a process whose nuclides' lines are in this machine's cache (:func:`gamma_lines`:
# the detector, the vehicle and the launcher of every run) reads none of its tables.

MIN_LINE_KEV = 10.0  # lines below this never reach a 40 keV threshold
MIN_LINE_YIELD = 1e-3


@cache
def _nuclide(name: str) -> Nuclide:
    """``Nuclide.load(name)`` from pydecay's cached catalog, once per name and process: ``Nuclide.load`` parses the
    whole ICRP-107 table (0.9 MB of JSON, ~45 ms) on every call, and one scene's validation made ~20 such calls.
    Raises pydecay's NuclideNotFoundError / DataFormatError as ``Nuclide.load`` does (errors are not cached)."""
    from pydecay.data import load_catalog
    from pydecay.exceptions import NuclideNotFoundError
    from pydecay.nuclide import Nuclide, normalize_nuclide_name

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
    from pydecay.data import load_rad_for

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


def _pydecay_version() -> str:
    return machine_cache.package_version("pydecay")


def _rad_file() -> Path | None:
    return machine_cache.package_file("pydecay", "data", "icrp107_rad.json.gz")


def rows_cache() -> Path | None:
    """The folder caching pydecay's RAD rows on this machine (None when pydecay's table cannot be stat'ed)."""
    return machine_cache.keyed_path("pydecay-rad-rows", _pydecay_version(), _rad_file())


def lines_cache() -> Path | None:
    """The folder caching :func:`gamma_lines` on this machine: keyed by pydecay's version and both tables the lines
    come from (the ICRP-107 catalog's half-lives and branchings, the RAD rows)."""
    return machine_cache.keyed_path("pydecay-gamma-lines", _pydecay_version(),
                                    (machine_cache.package_file("pydecay", "data", "icrp107.json"), _rad_file()))


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


def chain_members(head: str, follow: Callable[[Any, float], bool], max_depth: int) -> dict[str, float]:
    """Decays of ``head`` and of the progeny its decay chain reaches, per decay of ``head``: a radioactive daughter
    is walked, weighted by pydecay's branching ratios, when ``follow(daughter Nuclide, weight)`` says so, down to
    ``max_depth`` generations (each member decaying at the rate its parents feed it: equilibrium)."""
    members: dict[str, float] = {}

    def walk(name: str, weight: float, depth: int) -> None:
        members[name] = members.get(name, 0.0) + weight
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
                walk(d.name, w, depth + 1)

    walk(head, 1.0, 0)
    return members


def member_photon_lines(members: dict[str, float]) -> dict[float, float]:
    """Photons per decay of the source (energy keV -> photons): each member's decays per decay of the source times
    its own ICRP-107 emissions (:func:`add_photon_lines`)."""
    lines: dict[float, float] = {}
    for name, w in members.items():
        add_photon_lines(lines, name, w)
    return lines


def chain_photon_lines(head: str, follow: Callable[[Any, float], bool], max_depth: int) -> dict[float, float]:
    """Photons per decay of ``head`` (energy keV -> photons, :func:`add_photon_lines`) with those of the
    progeny its decay chain reaches (:func:`chain_members`)."""
    return member_photon_lines(chain_members(head, follow, max_depth))


def short_lived_members(head: str) -> dict[str, float]:
    """``head`` with the daughters much shorter-lived than it (secular equilibrium within weeks, e.g. Ba-137m under
    Cs-137, Th-234 and Pa-234m under U-238), per decay of ``head`` (:func:`chain_members`)."""
    t = _nuclide(head).half_life_s
    return chain_members(head, max_depth=3,
                         follow=lambda d, _w: d.half_life_s < 1e-3 * t and d.half_life_s < 30 * 86400)


def _kept(lines: dict[float, float], min_yield: float) -> tuple[tuple[float, float], ...]:
    return tuple(sorted((e, y) for e, y in lines.items() if y >= min_yield))


@lru_cache(maxsize=64)
def gamma_lines(nuclide: str, min_yield: float = MIN_LINE_YIELD) -> tuple[tuple[float, float], ...]:
    """(energy keV, photons per decay of ``nuclide``) from pydecay's ICRP-107 tables.

    Daughters much shorter-lived than the parent (secular equilibrium, e.g. Ba-137m under Cs-137)
    contribute with their branching ratio. Raises ``ValueError`` naming an unknown nuclide. The lines of a name asked
    for before on this machine come from :func:`lines_cache` (pydecay's own values, computed by it the first time).
    """
    path = None
    folder = lines_cache()
    if folder is not None and _SAFE_NAME.fullmatch(nuclide):
        path = folder / f"{nuclide}@{min_yield!r}.json"
        cached = machine_cache.read_json(path)
        if isinstance(cached, list) and cached and all(
                isinstance(r, list) and len(r) == 2 and all(isinstance(x, float) for x in r) for r in cached):
            return tuple((e, y) for e, y in cached)
    try:
        parent = _nuclide(nuclide)
    except Exception as exc:  # pydecay raises its own NuclideNotFoundError / DataFormatError
        raise ValueError(f"unknown nuclide {nuclide!r} ({exc})") from None
    out = _kept(member_photon_lines(short_lived_members(parent.name)), min_yield)
    if not out:
        raise ValueError(f"nuclide {nuclide!r} emits no gamma line above {MIN_LINE_KEV} keV in pydecay's tables")
    machine_cache.write_json(path, [[float(e), float(y)] for e, y in out])
    return out


#: heads of the natural decay series. As a calibration source (``radseek calibrate X=Th-232``) the bare name means the
#: head with its whole chain in secular equilibrium, as in ore, radium dials and thorium decades after its chemistry:
#: every member decays at the head's rate times its branching. ``HEAD@AGE`` is the chain AGE after the head's
#: element was separated (a mantle or a welding rod a few years old: :func:`aged_members`). (K-40 has no radioactive
#: progeny: ``gamma_lines("K-40")`` is already its whole emission.)
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
    return _kept(member_photon_lines(equilibrium_members(head)), min_yield)


@lru_cache(maxsize=16)
def equilibrium_members(head: str) -> dict[str, float]:
    """Decays of every member of ``head``'s whole chain per decay of ``head``, in secular equilibrium."""
    try:
        _nuclide(head)
    except Exception as exc:  # pydecay raises its own NuclideNotFoundError / DataFormatError
        raise ValueError(f"unknown nuclide {head!r} ({exc})") from None
    return chain_members(head, max_depth=40, follow=lambda _d, w: w >= CHAIN_MIN_BRANCH)  # cached: never mutated


#: natural uranium separated from its daughters (``radseek calibrate glass.xml=U-nat``): uranium glass and glaze,
#: yellowcake. Chemistry keeps the uranium isotopes and removes thorium and radium; within months Th-234 and Pa-234m
#: grow back to U-238's activity, and Th-231 to U-235's, while Th-230 (75,000 y) holds Ra-226 and its lines back for
#: millennia. U-234 is uranium and stays at U-238's activity. ``U-nat@AGE`` grows the daughters in by Bateman's
#: solution instead (:func:`aged_members`); the bare name is that with the short-lived daughters in equilibrium.
FRESH_URANIUM = "U-nat"
#: atom ratio U-235 / U-238 of natural uranium: 0.007204 / 0.992742, CIAAW / IUPAC isotopic abundances (Meija et
#: al., Pure Appl. Chem. 88 (2016) 293); the activity ratio follows with pydecay's half-lives (0.0461)
NATURAL_U235_U238_ATOMS = 0.007204 / 0.992742


def natural_uranium_activity_ratio() -> float:
    """Activity of U-235 per U-238 decay in natural uranium: the atom ratio times T(U-238) / T(U-235)."""
    t238 = _nuclide("U-238").half_life_s
    t235 = _nuclide("U-235").half_life_s
    return NATURAL_U235_U238_ATOMS * t238 / t235


#: ``HEAD@AGE``: HEAD's element chemically separated AGE ago (``radseek calibrate rod.xml=Th-232@5y``)
AGE_SEPARATOR = "@"
#: an age's units in seconds: the Julian year (365.25 d, the year of ICRP-107's half-lives) and the day
AGE_UNITS_S = {"y": 365.25 * 86400.0, "d": 86400.0}
#: the oldest age computed. Seed by seed, pydecay's solver agrees with Bateman's closed form (80-digit arithmetic)
#: within 2e-6 of the head's activity up to 1000 y for the thorium, radium and uranium labels, but U-234 grown from
#: U-238 is 4e-4 off at 10^4 y and 2 % at 10^5 y (pydecay 0.6.1). Thorium and radium are in equilibrium long before
#: 1000 y; older uranium (ore) is the bare head, the whole chain in secular equilibrium.
MAX_AGE_Y = 1000.0
_AGE = re.compile(r"\s*(\d+(?:\.\d*)?|\.\d+)(?:[eE]([+-]?\d+))?\s*([a-zA-Z]+)\s*")


def parse_source_label(name: str) -> tuple[str, float | None]:
    """``HEAD@AGE`` -> (HEAD, age in seconds); a bare name -> (name, None). ``ValueError`` in one line naming the
    label: no head, an age that is not a number with a unit of ``AGE_UNITS_S``, negative, or above ``MAX_AGE_Y``."""
    head, sep, age = name.partition(AGE_SEPARATOR)
    if not sep:
        return name, None
    example = f"{head.strip() or 'Th-232'}{AGE_SEPARATOR}20y"
    if not head.strip():
        raise ValueError(f"{name!r}: no source before {AGE_SEPARATOR!r} (e.g. Th-232{AGE_SEPARATOR}20y)")
    if age.strip().startswith("-"):
        raise ValueError(f"{name!r}: the age since the source's chemistry cannot be negative (e.g. {example})")
    m = _AGE.fullmatch(age)
    if not m or m.group(3) not in AGE_UNITS_S:
        raise ValueError(f"{name!r}: the age after {AGE_SEPARATOR!r} must be a number and a unit, y (years) or "
                         f"d (days), e.g. {example}")
    value = float(m.group(1) + (f"e{m.group(2)}" if m.group(2) else ""))
    if value * AGE_UNITS_S[m.group(3)] > MAX_AGE_Y * AGE_UNITS_S["y"]:
        raise ValueError(f"{name!r}: ages above {MAX_AGE_Y:g} y are not computed; a bare {head.strip()!r} is "
                         f"its chain in secular equilibrium")
    return head.strip(), value * AGE_UNITS_S[m.group(3)]


def _element(name: str) -> str:
    return name.split("-", 1)[0]


def separated_seeds(head: str) -> dict[str, float]:
    """Activity per decay of the head of what a chemical separation of the head's element from its ore leaves:
    every isotope of that element in the head's chain at its secular-equilibrium activity (the ore's), no member of
    another element. Th-232: Th-232 and Th-228 at 1 (Ra-228 and Ra-224 removed); U-238: U-238 and U-234; ``U-nat``:
    those and U-235 at ``natural_uranium_activity_ratio``."""
    if head == FRESH_URANIUM:
        seeds = separated_seeds("U-238")
        for n, a in separated_seeds("U-235").items():
            seeds[n] = seeds.get(n, 0.0) + natural_uranium_activity_ratio() * a
        return seeds
    head = _nuclide_or_value_error(head).name  # pydecay's spelling: the walk's members are named so
    return {n: w for n, w in equilibrium_members(head).items() if _element(n) == _element(head)}


def _nuclide_or_value_error(name: str) -> Nuclide:
    try:
        return _nuclide(name)
    except Exception as exc:  # pydecay raises its own NuclideNotFoundError / DataFormatError
        raise ValueError(f"unknown nuclide {name!r} ({exc})") from None


@cache
def _unit_inventory(seed: str) -> Inventory:
    """1 Bq of ``seed`` alone, with its progeny closure (pydecay loads every member once here)."""
    from pydecay import Inventory

    return Inventory({seed: 1.0})


@lru_cache(maxsize=32)
def aged_members(head: str, age_s: float) -> dict[str, float]:
    """Decays of each member per decay of the head (U-238 for ``U-nat``), ``age_s`` after the head's element was
    separated (:func:`separated_seeds`): pydecay's Bateman ingrowth (``Inventory.decay``) of every member.

    Each seed is decayed on its own and the activities added (the equations are linear): pydecay's matrix
    exponential of the joint state (Th-232 beside Th-228, whose atoms are 10^-10 of Th-232's) put Ra-228 0.8 % off
    the closed form at 20 y, while seed by seed it agrees to 10^-14 (measured on pydecay 0.6.1)."""
    ref = "U-238" if head == FRESH_URANIUM else _nuclide_or_value_error(head).name
    act: dict[str, float] = {}
    for seed, a in separated_seeds(head).items():
        for n, v in _unit_inventory(seed).decay(age_s).activities().items():
            act[n] = act.get(n, 0.0) + a * float(v)
    per = act[ref]
    if not per > 0.0:
        raise ValueError(f"{head}{AGE_SEPARATOR}{age_s / AGE_UNITS_S['y']:g}y: the head has decayed away")
    return {n: v / per for n, v in act.items() if v > 0.0}


def source_members(name: str) -> dict[str, float]:
    """Decays of each member per decay of a calibration source: ``HEAD@AGE`` grown in since its chemistry
    (:func:`aged_members`), a natural chain head (``NATURAL_CHAINS``) in secular equilibrium, ``FRESH_URANIUM`` with
    its short-lived daughters, any other nuclide with its short-lived daughters. ``ValueError`` names a bad label."""
    head, age_s = parse_source_label(name)
    if age_s is not None:
        try:
            return dict(aged_members(head, age_s))
        except ValueError as exc:
            raise ValueError(f"{name!r}: {exc}") from None
    if name == FRESH_URANIUM:
        members: dict[str, float] = {}
        for seed, a in separated_seeds(FRESH_URANIUM).items():
            for n, w in short_lived_members(seed).items():
                members[n] = members.get(n, 0.0) + a * w
        return members
    if name in NATURAL_CHAINS:
        return dict(equilibrium_members(name))
    return short_lived_members(_nuclide_or_value_error(name).name)


def is_chain_source(name: str) -> bool:
    """A natural source named for its chain (a chain head, ``U-nat``, ``HEAD@AGE``): a calibration source, not a
    flight source, so a detector file carries no template for it."""
    return name in NATURAL_CHAINS or name == FRESH_URANIUM or AGE_SEPARATOR in name


@lru_cache(maxsize=64)
def source_lines(name: str) -> tuple[tuple[float, float], ...]:
    """Photon lines (energy keV, photons per decay of the head) of a calibration source (:func:`source_members`):
    each member's decays times its ICRP-107 emissions; any other nuclide's are ``gamma_lines``."""
    if not is_chain_source(name):
        return gamma_lines(name)
    return _kept(member_photon_lines(source_members(name)), MIN_LINE_YIELD)
