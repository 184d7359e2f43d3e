"""pydecay's NIST XCOM table of its shielding materials (mass attenuation mu/rho at 45 energies, and each material's
density), read through pydecay once per machine and from this machine's cache after (radseek.machine_cache).

Importing pydecay costs a process 0.3 s of CPU (pint's unit registry, scipy.linalg); the detector, the vehicle and
the launcher of every run need a few of these values (a scene's wall materials, a wall's attenuation). The values
are pydecay's own, interpolated as ``pydecay.materials.Material.mu_over_rho`` interpolates them (linear in
log E and log mu/rho, an energy outside the table an error), vectorised; tests/test_xcom.py holds them to pydecay.
"""

from __future__ import annotations

from functools import cache

import numpy as np

from radseek import machine_cache


def _valid(table: object) -> bool:
    if not isinstance(table, dict) or not table:
        return False
    for entry in table.values():
        if not (isinstance(entry, dict) and isinstance(entry.get("density_g_cm3"), float)
                and isinstance(entry.get("E_MeV"), list) and isinstance(entry.get("mu_over_rho"), list)
                and len(entry["E_MeV"]) == len(entry["mu_over_rho"]) >= 2):
            return False
    return True


@cache
def table() -> dict[str, dict]:
    """Material (lower case) -> {"density_g_cm3", "E_MeV", "mu_over_rho"}: pydecay's payload, as its registry reads
    it (``pydecay.available_materials`` names, ``pydecay.material`` values)."""
    path = machine_cache.keyed_path("pydecay-xcom", machine_cache.package_version("pydecay"),
                                    machine_cache.package_file("pydecay", "data", "nist_mu.json.gz"), ".json")
    cached = machine_cache.read_json(path)
    if _valid(cached):
        return cached
    from pydecay._dose_data import load_nist_mu  # the payload pydecay's material registry is built from

    out = {str(name).lower(): {"density_g_cm3": float(e["density_g_cm3"]), "E_MeV": [float(x) for x in e["E_MeV"]],
                               "mu_over_rho": [float(x) for x in e["mu_over_rho"]]}
           for name, e in load_nist_mu()["materials"].items()}
    machine_cache.write_json(path, out)
    return out


def material_names() -> list[str]:
    """The materials pydecay knows (``pydecay.available_materials()``)."""
    return sorted(table())


def density_g_cm3(material: str) -> float:
    return float(_entry(material)["density_g_cm3"])


def _entry(material: str) -> dict:
    try:
        return table()[material.lower()]
    except KeyError:
        raise ValueError(f"unknown material {material!r}; known: {', '.join(material_names())}") from None


@cache
def _logs(material: str) -> tuple[np.ndarray, np.ndarray]:
    e = _entry(material)
    return np.log(np.asarray(e["E_MeV"], dtype=float)), np.log(np.asarray(e["mu_over_rho"], dtype=float))


def mu_over_rho(material: str, energy_MeV: float | np.ndarray) -> np.ndarray:
    """mu/rho (cm^2/g) of ``material`` at ``energy_MeV``: log-log interpolation in pydecay's table; an energy
    outside it is a ValueError, as pydecay's MaterialError is."""
    log_e, log_mu = _logs(material.lower())
    e = np.asarray(energy_MeV, dtype=float)
    nodes = _entry(material)["E_MeV"]
    lo, hi = nodes[0], nodes[-1]
    if not np.all(np.isfinite(e)) or np.any(e < lo) or np.any(e > hi):
        raise ValueError(f"{material}: energy {energy_MeV!r} MeV outside the table range [{lo}, {hi}] MeV")
    return np.exp(np.interp(np.log(e), log_e, log_mu))
