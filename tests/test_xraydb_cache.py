"""The detector response's photo-absorption cross-sections of Cs and I below 150 keV come from xraydb (Elam's
tables) through this machine's cache (``detector_fw_sim.response._mu_elam_photo``, ``radseek.machine_cache``):
what it reads is xraydb's own value, from a cold cache and a warm one; a warm cache needs no xraydb import; a
changed database is another cache, and an unusable cache is xraydb itself."""

from __future__ import annotations

import builtins
import json
import os

import pytest
import xraydb

from detector_fw_sim import response
from radseek import machine_cache

ENERGIES_EV = (1000.0, 5000.0, 33169.0, 36000.0, 59540.9, 149999.0)


@pytest.fixture
def cold_cache(tmp_path, monkeypatch):
    """An empty cache folder of this test's own, and no value read in this process yet (restored after)."""
    monkeypatch.setenv(machine_cache.CACHE_ENV, str(tmp_path / "cache"))
    response._elam_values.cache_clear()
    yield tmp_path / "cache"
    response._elam_values.cache_clear()


def _xraydbs(el: str, e: float) -> float:
    return float(xraydb.mu_elam(el, e, kind="photo"))


def _fresh_process_reads(el: str, e: float) -> float:
    response._elam_values.cache_clear()
    return response._mu_elam_photo(el, e)


def test_values_written_once_are_read_back_without_xraydb(cold_cache, monkeypatch):
    for el in ("Cs", "I"):
        for e in ENERGIES_EV:
            assert response._mu_elam_photo(el, e) == _xraydbs(el, e), (el, e)
    path = response._elam_file()
    assert path.parent == cold_cache and len(json.loads(path.read_text())) == 2 * len(ENERGIES_EV)
    real_import = builtins.__import__

    def no_xraydb(name, *args, **kwargs):
        if name.split(".")[0] == "xraydb":
            raise ImportError(f"import {name}: the cache should have had it")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_xraydb)  # any `import xraydb` now fails
    for el in ("Cs", "I"):
        for e in ENERGIES_EV:
            assert _fresh_process_reads(el, e) == _xraydbs(el, e), (el, e)
    with pytest.raises(ImportError):  # a value not in the cache is computed by xraydb: none here
        _fresh_process_reads("Cs", 12345.0)
    assert not [p for p in cold_cache.iterdir() if p != path]  # no temporary file left behind


def test_the_cache_is_keyed_by_xraydbs_database(cold_cache, tmp_path):
    db = tmp_path / "xraydb.sqlite"
    db.write_bytes(b"a database")
    first = machine_cache.keyed_path("xraydb-mu-elam-photo", "4.5", db, ".json")
    os.utime(db, ns=(0, db.stat().st_mtime_ns + 10**9))
    assert machine_cache.keyed_path("xraydb-mu-elam-photo", "4.5", db, ".json") != first
    os.utime(db, ns=(0, db.stat().st_mtime_ns - 10**9))
    assert machine_cache.keyed_path("xraydb-mu-elam-photo", "4.5", db, ".json") == first
    assert machine_cache.keyed_path("xraydb-mu-elam-photo", "4.6", db, ".json") != first
    assert machine_cache.keyed_path("xraydb-mu-elam-photo", "4.5", tmp_path / "none.sqlite", ".json") is None
    # the response's cache is named by the installed xraydb's database, and trusted for it: a value cached there is
    # the one read
    path = response._elam_file()
    assert path.parent == cold_cache and path.name.startswith("xraydb-mu-elam-photo-")
    path.parent.mkdir(parents=True)
    path.write_text(json.dumps({"Cs 33169.0": 1.5}))
    assert _fresh_process_reads("Cs", 33169.0) == 1.5


def test_an_unusable_cache_falls_back_to_xraydb(tmp_path, monkeypatch, cold_cache):
    (tmp_path / "blocked").write_text("not a folder")
    monkeypatch.setenv(machine_cache.CACHE_ENV, str(tmp_path / "blocked" / "cache"))
    assert _fresh_process_reads("I", 36000.0) == _xraydbs("I", 36000.0)
    monkeypatch.setenv(machine_cache.CACHE_ENV, str(cold_cache))
    path = response._elam_file()
    path.parent.mkdir(parents=True)
    for bad in ('{"I 36000.0": 1.', '["not", "ours"]', '{"I 36000.0": "x"}'):
        path.write_text(bad)
        assert _fresh_process_reads("I", 36000.0) == _xraydbs("I", 36000.0), bad
        assert json.loads(path.read_text()) == {"I 36000.0": _xraydbs("I", 36000.0)}
