"""radseek.photon_lines reads pydecay's tables once per process (``_nuclide``, ``_emissions``), and pydecay's RAD
rows once per machine (``rows_cache``): what it reads is what pydecay's own ``Nuclide.load`` and ``emissions`` give,
for every member of the natural chains and for names pydecay does not know, from a cold cache and a warm one; a
changed table is another cache, and an unusable cache is pydecay's table."""

from __future__ import annotations

import json
import os

import pydecay
import pydecay.data
import pytest
from pydecay.exceptions import NuclideNotFoundError
from pydecay.nuclide import Nuclide

from radseek import photon_lines
from radseek.photon_lines import NATURAL_CHAINS, _emissions, _nuclide, chain_photon_lines


def _members() -> set[str]:
    """Every nuclide the natural chains' walk visits, and the sources the tests calibrate with."""
    seen: set[str] = {"Cs-137", "Ba-137m", "Co-60", "Ba-133", "Am-241", "Eu-152", "K-40", "cs137"}

    def follow(d: Nuclide, _w: float) -> bool:
        seen.add(d.name)
        return True

    for head in NATURAL_CHAINS:
        seen.add(head)
        chain_photon_lines(head, follow=follow, max_depth=40)
    return seen


@pytest.fixture(scope="module")
def pydecays_own() -> dict[str, tuple[Nuclide, tuple]]:
    """What pydecay's own ``Nuclide.load`` and ``emissions`` give for every member (each uncached: 45 ms a call)."""
    return {name: (Nuclide.load(name), _pydecay_rows(name)) for name in sorted(_members())}


def _pydecay_rows(name: str) -> tuple:
    try:
        return tuple(pydecay.emissions(name))
    except Exception:  # noqa: BLE001 - pydecay's own errors: no emissions
        return ()


def test_the_cached_reads_are_pydecays_own(pydecays_own):
    assert len(pydecays_own) > 30  # the chains' members, not only their heads
    for name, (nuclide, rows) in pydecays_own.items():
        assert _nuclide(name) == nuclide, name
        assert _emissions(name) == rows, name
    assert _nuclide("Cs-137") is _nuclide("Cs-137")  # read once


def test_an_unknown_name_raises_as_pydecay_does_and_has_no_emissions():
    with pytest.raises(NuclideNotFoundError) as ours:
        _nuclide("Xx-999")
    with pytest.raises(NuclideNotFoundError) as theirs:
        Nuclide.load("Xx-999")
    assert str(ours.value) == str(theirs.value)
    assert _emissions("Xx-999") == ()


# ---- the per-machine cache of pydecay's RAD rows (radseek.photon_lines.rows_cache)


@pytest.fixture
def cold_cache(tmp_path, monkeypatch):
    """An empty cache folder of this test's own, and no rows read in this process yet (restored after)."""
    monkeypatch.setenv(photon_lines.CACHE_ENV, str(tmp_path / "cache"))
    photon_lines._emissions.cache_clear()
    yield tmp_path / "cache"
    photon_lines._emissions.cache_clear()


def _fresh_process_reads(name: str) -> tuple:
    """``_emissions(name)`` as a new process reads it: nothing in memory, the cache read again."""
    photon_lines._emissions.cache_clear()
    return _emissions(name)


def test_rows_written_once_are_read_back_without_pydecays_table(cold_cache, monkeypatch, pydecays_own):
    expected = {name: rows for name, (_, rows) in pydecays_own.items()}
    for name, rows in expected.items():  # cold: read from pydecay's table, written to the cache
        assert _emissions(name) == rows, name
    folder = photon_lines.rows_cache()
    assert folder.parent == cold_cache and len(list(folder.glob("*.json"))) == len({_nuclide(n).name for n in expected})

    def no_table(name):
        raise AssertionError(f"pydecay's RAD table parsed for {name}")

    monkeypatch.setattr(pydecay.data, "load_rad_for", no_table)  # what _emissions imports when it reads the table
    for name, rows in expected.items():  # warm: every row from the cache, each equal to pydecay's own
        assert _fresh_process_reads(name) == rows, name
    assert _fresh_process_reads("Xx-999") == ()
    assert not list(folder.glob(".*"))  # no temporary file left behind


def test_the_cache_is_keyed_by_pydecays_table(cold_cache, monkeypatch, tmp_path):
    table = tmp_path / "icrp107_rad.json.gz"
    table.write_bytes(photon_lines._rad_file().read_bytes())
    monkeypatch.setattr(photon_lines, "_rad_file", lambda: table)
    first = photon_lines.rows_cache()
    # rows cached for this table are read, whatever they say (the cache is trusted for its own key) ...
    first.mkdir(parents=True)
    (first / "Cs-137.json").write_text(json.dumps([{"E_MeV": 1.0, "prob": 0.5, "is_photon": True}]))
    assert _fresh_process_reads("Cs-137") == ({"E_MeV": 1.0, "prob": 0.5, "is_photon": True},)
    # ... and a changed table (a new modification time) or another pydecay version is another folder: pydecay's rows
    os.utime(table, ns=(0, table.stat().st_mtime_ns + 10**9))
    assert photon_lines.rows_cache() != first
    assert _fresh_process_reads("Cs-137") == _pydecay_rows("Cs-137")
    os.utime(table, ns=(0, table.stat().st_mtime_ns - 10**9))
    assert photon_lines.rows_cache() == first
    assert photon_lines._pydecay_version() == pydecay.__version__  # read without importing pydecay
    monkeypatch.setattr(photon_lines, "_pydecay_version", lambda: "0.0.0-other")
    assert photon_lines.rows_cache() != first


def test_an_unusable_cache_falls_back_to_pydecays_table(tmp_path, monkeypatch, cold_cache):
    # a cache folder that cannot be created (a file stands in its place): rows from pydecay, nothing raised
    (tmp_path / "blocked").write_text("not a folder")
    monkeypatch.setenv(photon_lines.CACHE_ENV, str(tmp_path / "blocked" / "cache"))
    assert _fresh_process_reads("Co-60") == _pydecay_rows("Co-60") != ()
    # an unreadable cache file (truncated, or not ours): rows from pydecay, and the file written anew
    monkeypatch.setenv(photon_lines.CACHE_ENV, str(cold_cache))
    path = photon_lines.rows_cache() / "Co-60.json"
    path.parent.mkdir(parents=True)
    for bad in ('[{"E_MeV": 1.1', '{"not": "ours"}', '["x"]'):
        path.write_text(bad)
        assert _fresh_process_reads("Co-60") == _pydecay_rows("Co-60"), bad
        assert json.loads(path.read_text()) == list(_pydecay_rows("Co-60"))
