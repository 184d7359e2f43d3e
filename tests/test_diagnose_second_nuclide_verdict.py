"""A second source of another nuclide, named by ``radseek diagnose`` on a flight of the independent generator
(benchmarks/forward2: a made-up "wide" crystal, scattered photons): its spectrum joins the spectral verdict, so
a model that has it is adequate, and the verdict without it still sees the nuclide mix change over the flight.
"""

from __future__ import annotations

import numpy as np
import pytest

from estimator.diagnose.verdict import SPECTRAL_Z, spectral_channel_z
from tests.support.co60_second import co60_second_diagnosis

#: a whole diagnose call (~25 s of CPU, shared with test_diagnose_verdict) behind both tests: not the unit tier's
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def co60_second(tmp_path_factory):
    return co60_second_diagnosis(tmp_path_factory)  # the flight's spec: tests/support/co60_second.py


def test_a_co60_second_source_is_named_with_its_nuclide_and_the_model_with_it_is_adequate(co60_second):
    ds, d = co60_second
    assert d.missing == ["second_source"] and not d.unexplained, (d.missing, d.partial)
    assert d.nuclide is not None and d.nuclide.nuclide == "Co-60"
    z = spectral_channel_z(d.final_report)
    assert len(z) == 32 and z.max() < SPECTRAL_Z
    x, y = d.final_report.fit.values["second_source.x"], d.final_report.fit.values["second_source.y"]
    assert np.hypot(x - 1.5, y - 1.5) < 1.0


def test_one_source_spectrum_cannot_follow_the_nuclide_mix(co60_second):
    """The flight's spectrum changes shape as the share of Co-60 changes: with a single source template (the
    verdict of a model without the second source) the channels of Co-60's lines and Compton continuum misfit."""
    _, d = co60_second
    z = spectral_channel_z(d.current)
    assert z.max() > SPECTRAL_Z
