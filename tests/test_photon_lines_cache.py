"""radseek.photon_lines reads pydecay's tables once per process (``_nuclide``, ``_emissions``): what it reads is
what pydecay's own ``Nuclide.load`` and ``emissions`` give, for every member of the natural chains and for names
pydecay does not know."""

from __future__ import annotations

import pydecay
import pytest
from pydecay.exceptions import NuclideNotFoundError
from pydecay.nuclide import Nuclide

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


def test_the_cached_reads_are_pydecays_own():
    names = _members()
    assert len(names) > 30  # the chains' members, not only their heads
    for name in sorted(names):
        assert _nuclide(name) == Nuclide.load(name), name
        try:
            rows = tuple(pydecay.emissions(name))
        except Exception:  # noqa: BLE001 - pydecay's own errors: no emissions
            rows = ()
        assert _emissions(name) == rows, name
    assert _nuclide("Cs-137") is _nuclide("Cs-137")  # read once


def test_an_unknown_name_raises_as_pydecay_does_and_has_no_emissions():
    with pytest.raises(NuclideNotFoundError) as ours:
        _nuclide("Xx-999")
    with pytest.raises(NuclideNotFoundError) as theirs:
        Nuclide.load("Xx-999")
    assert str(ours.value) == str(theirs.value)
    assert _emissions("Xx-999") == ()
