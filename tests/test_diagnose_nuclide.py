"""Which nuclide the second source is (estimator.diagnose.nuclide), checked on flights built from MEASURED spectra.

The synthetic flights draw their counts from RadiaCode-102 measurements (shared/real-spectra: Cs-137, Co-60,
Ba-133, Eu-152 check sources, background subtracted by live time, the room background, and Am-241 measured on
another RC-102), rebinned onto the
shared datasets' comparator edges with ``benchmarks.forward2`` (an independent forward model's rebinning): the
identification never saw these shapes, it knows only pydecay's line energies and xraydb's cross-sections.
"""

from __future__ import annotations

import json
from functools import lru_cache
from pathlib import Path

import numpy as np
import pytest

from benchmarks.forward2.spectra import EDGES, REAL_SPECTRA, scatter_response
from estimator.diagnose.nuclide import (
    CANDIDATES,
    NuclideChoice,
    calibrate,
    channel_shape,
    group_labels,
    identify_second_nuclide,
    photon_lines,
)
from radseek.dataset import Frames
from radseek_io.dataset import read_dataset
from radseek_io.spectrum_io import read_spectrum

FILES = {"Cs-137": "Cs137_b.xml", "Co-60": "Co60_a.xml", "Ba-133": "Ba133_a.xml", "Eu-152": "Eu152_b.xml"}
TWO_SOURCES = REAL_SPECTRA.parent / "datasets" / "two-sources"

needs_spectra = pytest.mark.skipif(not (REAL_SPECTRA / "bg.xml").exists(), reason="shared/real-spectra missing")


@lru_cache(maxsize=8)
def measured(name: str) -> np.ndarray:
    """Channel shares on the comparator edges: net of the room background (by live time) for a nuclide,
    the background itself for 'bg'."""
    bg = read_spectrum(Path(REAL_SPECTRA) / "bg.xml")
    if name == "bg":
        c = bg.rebin(EDGES)
    elif name == "Am-241":  # another RC-102, no background of its own: ~500 cps of source against ~5 of room
        c = read_spectrum(Path(REAL_SPECTRA) / "data_am241.n42").rebin(EDGES)
    else:
        s = read_spectrum(Path(REAL_SPECTRA) / FILES[name])
        c = np.clip(s.rebin(EDGES) - bg.rebin(EDGES) * s.livetime / bg.livetime, 0.0, None)
    return c / c.sum()


def flight(primary: str, second: str, second_cps: float, seed: int, primary_cps: float = 2000.0,
           background_cps: float = 30.0, dwells: int = 40, dwell_s: float = 5.0, frame_s: float = 0.1,
           scatter_per_m: float = 0.0, data_second_cps: float | None = None, model_offset_m: float = 0.0
           ) -> tuple[Frames, dict[str, np.ndarray]]:
    """A dwell-only flight: ``dwells`` hover points at 1-2 m over a 12 m x 9 m field, a primary source and
    a second one 4-5 m apart on the floor; per-frame counts drawn from the measured shapes. Returns the frames
    and the true expected total counts per frame of each component (inverse square, as the count model);
    ``model_offset_m``: the expected second-source counts are those of a source that far off the true one
    (a count fit that placed it wrong), ``data_second_cps``: the strength in the data when not the model's."""
    rng = np.random.default_rng(seed)
    s1 = np.array([3.5 + rng.uniform(-0.5, 0.5), 5.0 + rng.uniform(-0.5, 0.5), 0.0])
    s2 = np.array([8.0 + rng.uniform(-0.5, 0.5), 3.0 + rng.uniform(-0.5, 0.5), 0.0])
    # half the dwells around each source (the search visits both), a few far ones
    pts = []
    for i in range(dwells):
        c = (s1, s2)[i % 2] if i % 8 else np.array([rng.uniform(0, 12), rng.uniform(0, 9), 0.0])
        r, a = rng.uniform(0.0, 3.0), rng.uniform(0, 2 * np.pi)
        pts.append([c[0] + r * np.cos(a), c[1] + r * np.sin(a), rng.uniform(1.0, 2.0)])
    per = round(dwell_s / frame_s)
    pos = np.repeat(np.array(pts), per, axis=0)
    n = len(pos)
    dur = np.full(n, frame_s)
    t = np.cumsum(dur)
    d1 = ((pos - s1) ** 2).sum(1)
    d2 = ((pos - s2) ** 2).sum(1)
    s2_model = s2 + np.array([model_offset_m, 0.0, 0.0])
    e = {"primary": primary_cps / d1 * dur, "second": second_cps / ((pos - s2_model) ** 2).sum(1) * dur,
         "background": background_cps * dur}
    e2 = (second_cps if data_second_cps is None else data_second_cps) / d2 * dur
    # scattered photons grow with distance (the primary's shape changes along the flight): a share
    # min(scatter_per_m d, 0.5) of each source's counts is the forward model's down-scattered continuum
    sc = scatter_response().channel_probs(EDGES, np.ones(1))[0]
    sc = sc / sc.sum()
    f1 = np.minimum(scatter_per_m * np.sqrt(d1), 0.5)[:, None]
    f2 = np.minimum(scatter_per_m * np.sqrt(d2), 0.5)[:, None]
    mu = (e["primary"][:, None] * ((1 - f1) * measured(primary) + f1 * sc)
          + e2[:, None] * ((1 - f2) * measured(second) + f2 * sc)
          + np.outer(e["background"], measured("bg")))
    counts = rng.poisson(mu)
    z = np.zeros(n)
    frames = Frames(t=t, duration=dur, x=pos[:, 0], y=pos[:, 1], z=pos[:, 2], yaw=z, var_x=z + 1e-3,
                    var_y=z + 1e-3, var_z=z + 1e-3, dwell=np.repeat(np.arange(dwells), per), counts=counts)
    return frames, e


def identify(frames: Frames, e: dict[str, np.ndarray], primary: str, **kw) -> NuclideChoice:
    """The identification of the second source's nuclide (its CPU per call: benchmarks/nuclide_identify.py)."""
    return identify_second_nuclide(frames, EDGES, primary, e["primary"], e["second"], e["background"], **kw)


# ------------------------------------------------------------------------------------------------ the pieces


def test_lines_come_from_the_library_with_short_lived_daughters():
    import pydecay

    cs = dict(photon_lines("Cs-137"))
    # Cs-137 itself emits no gamma: its 662 keV line is Ba-137m's, weighted by the branching to Ba-137m
    ba137m = max((r for r in pydecay.emissions("Ba-137m") if r.get("is_photon") and r["E_MeV"] > 0.1),
                 key=lambda r: r["prob"])
    e662 = round(ba137m["E_MeV"] * 1000.0, 3)
    assert 0.8 < cs[e662] < ba137m["prob"]
    co = photon_lines("Co-60")
    assert sum(y for e, y in co if e > 1000) == pytest.approx(2.0, abs=0.01)
    with pytest.raises(ValueError, match="unknown nuclide"):
        photon_lines("Xx-999")


def test_group_labels_split_dwells_and_chunk_transit():
    n = 60
    dwell = np.r_[np.full(20, -1), np.full(20, 3), np.full(20, -1)]
    z = np.zeros(n)
    f = Frames(t=np.arange(n) * 0.1, duration=z + 0.1, x=z, y=z, z=z, yaw=z, var_x=z, var_y=z, var_z=z,
               dwell=dwell, counts=np.zeros((n, 32), dtype=int))
    lab = group_labels(f, chunk_s=1.0)
    assert np.all(np.diff(lab) >= 0)
    assert len(np.unique(lab[20:40])) == 1  # one dwell, one group
    assert len(np.unique(lab[:20])) == 2  # 2 s of transit in 1 s chunks


def test_the_response_is_linear_in_the_photons_and_keeps_every_decays_photons():
    # the crystal only mixes what the energies fix (cached once per set of energies): each path's photons are
    # the line's yield, and the deposits of two weightings add
    from estimator.diagnose.nuclide import Crystal, _deposits, _incident

    lines = photon_lines("Eu-152")
    for back, down in ((0.0, 0.0), (0.3, 0.2), (0.6, 0.4)):
        e, w = _incident(lines, Crystal(back=back, down=down))
        assert w.sum() == pytest.approx(sum(y for _, y in lines), rel=1e-12)
    e, w = _incident(lines, Crystal())
    rng = np.random.default_rng(0)
    w2 = rng.uniform(0, 1, len(w))
    for escape, fill in ((0.33, 0.3), (1.5, 0.9)):
        one, two, both = (_deposits(e, x, escape, fill) for x in (w, w2, w + w2))
        assert np.allclose(one[1] + two[1], both[1], rtol=1e-12, atol=0)
        assert np.allclose(one[2] + two[2], both[2], rtol=1e-12, atol=1e-12 * both[2].max())  # cumsum rounding
    # a longer path out of the crystal (escape_cm) means more second interactions: more in the photopeak
    assert _deposits(e, w, 2.0, 0.5)[1].sum() > _deposits(e, w, 0.1, 0.5)[1].sum()


@needs_spectra
def test_shapes_carried_from_the_primary_match_the_measured_spectra():
    # the crystal fitted on the MEASURED Cs-137 spectrum alone predicts Co-60, Ba-133 and Eu-152 (measured on
    # the same device, never seen by the fit) closer than any other candidate's prediction does
    crystal = calibrate("Cs-137", measured("Cs-137"), 20000.0, EDGES)
    for truth in ("Co-60", "Ba-133", "Eu-152"):
        tv = {c: 0.5 * np.abs(channel_shape(c, EDGES, crystal) - measured(truth)).sum() for c in CANDIDATES}
        assert min(tv, key=tv.get) == truth, tv
        others = min(v for c, v in tv.items() if c != truth)
        assert tv[truth] < 0.2 and others > 1.3 * tv[truth], tv


# ------------------------------------------------------------------------------------------------ flights


@needs_spectra
@pytest.mark.parametrize("second", ["Co-60", "Ba-133", "Eu-152", "Cs-137", "Am-241"])
@pytest.mark.slow
def test_second_nuclide_named_under_a_cs137_primary(second):
    # strong (1300 cps at 1 m, ~40k counts) and moderate (~60-100 cps, ~2-3k counts) second sources: at the
    # dwells near it the second source gives about as many counts as the primary 4-5 m away
    weak = 60.0 if second == "Eu-152" else 100.0
    for seed, cps in ((0, 1300.0), (1, 1300.0), (2, weak), (3, weak), (4, weak)):
        f, e = flight("Cs-137", second, cps, seed)
        choice = identify(f, e, "Cs-137")
        assert choice.nuclide == second, (seed, cps, choice.note, choice.log_likelihood)
        assert choice.gap >= 5.0
        assert set(choice.log_likelihood) == set(CANDIDATES)


@needs_spectra
def test_cs137_second_under_a_co60_primary():
    for seed, cps in ((0, 1300.0), (1, 300.0), (2, 100.0)):
        f, e = flight("Co-60", "Cs-137", cps, seed)
        choice = identify(f, e, "Co-60")
        assert choice.nuclide == "Cs-137", (seed, cps, choice.note)
        assert "Co-60" in choice.log_likelihood and choice.log_likelihood["Co-60"] < choice.log_likelihood["Cs-137"]


@needs_spectra
@pytest.mark.parametrize("second", ["Co-60", "Ba-133", "Eu-152"])
@pytest.mark.slow
def test_a_very_weak_second_source_is_not_given_a_wrong_nuclide(second):
    # ~60-120 second-source counts under ~45k of the primary: undetermined (None), never another nuclide
    outcomes = []
    for seed in range(3):
        f, e = flight("Cs-137", second, 2.0, seed)
        choice = identify(f, e, "Cs-137")
        assert choice.nuclide in (None, second), (seed, choice.note)
        outcomes.append(choice.nuclide)
        if choice.nuclide is None:
            assert "undetermined" in choice.note
    assert outcomes.count(None) >= 2, outcomes


@needs_spectra
def test_a_second_source_that_is_not_in_the_data_gets_no_nuclide():
    # the count model believes in a 1300 cps second source, the spectra hold none: every hypothesis fits alike
    for seed in range(2):
        f, e = flight("Cs-137", "Co-60", 1300.0, seed, data_second_cps=0.0)
        choice = identify(f, e, "Cs-137")
        assert choice.nuclide is None, choice.note


@needs_spectra
def test_a_nuclide_missing_from_the_candidates_is_not_replaced_by_a_neighbour():
    # a strong Co-60 second source, with Co-60 left out of the candidates: K-40 (one line at 1461 keV) is the
    # nearest, but leaves a misfit beyond the shapes' own error, so no nuclide is named
    f, e = flight("Cs-137", "Co-60", 1300.0, 0)
    cands = tuple(c for c in CANDIDATES if c != "Co-60")
    choice = identify(f, e, "Cs-137", candidates=cands)
    assert choice.nuclide is None and "none of" in choice.note, choice.note
    f, e = flight("Cs-137", "Eu-152", 1300.0, 1)
    choice = identify(f, e, "Cs-137", candidates=tuple(c for c in CANDIDATES if c != "Eu-152"))
    assert choice.nuclide is None, choice.note


@needs_spectra
def test_a_primary_whose_shape_changes_with_distance_does_not_make_a_nuclide_up():
    # scattered photons grow with distance (10 % per m, up to 50 %): the primary's shape is not one shape;
    # a phantom second source must still get no nuclide, a real Cs-137 one is still Cs-137
    f, e = flight("Cs-137", "Cs-137", 1300.0, 0, scatter_per_m=0.1, data_second_cps=0.0)
    assert identify(f, e, "Cs-137").nuclide is None
    f, e = flight("Cs-137", "Cs-137", 1300.0, 1, scatter_per_m=0.1)
    assert identify(f, e, "Cs-137").nuclide == "Cs-137"


def test_inputs_are_checked():
    z = np.zeros(3)
    f = Frames(t=np.arange(3.0), duration=z + 1, x=z, y=z, z=z, yaw=z, var_x=z, var_y=z, var_z=z,
               dwell=np.zeros(3, dtype=int), counts=np.ones((3, 32), dtype=int))
    with pytest.raises(ValueError, match="edges"):
        identify_second_nuclide(f, EDGES[:-1], "Cs-137", z + 1, z + 1, z + 1)
    with pytest.raises(ValueError, match="frames"):
        identify_second_nuclide(f, EDGES, "Cs-137", np.ones(4), np.ones(4), np.ones(4))
    none = identify_second_nuclide(f, EDGES, "Cs-137", z + 1, z, z + 1)
    assert none.nuclide is None and "no second-source counts" in none.note


# ------------------------------------------------------------------------------------------------ shared data


@pytest.mark.skipif(not (TWO_SOURCES / "frames.csv").exists(), reason="shared/datasets/two-sources missing")
def test_two_cs137_sources_dataset_calls_the_second_cs137():
    # the reference generator's flight over two Cs-137 sources; expected counts from the truth by inverse square
    ds = read_dataset(TWO_SOURCES)
    truth = json.loads((TWO_SOURCES / "truth.json").read_text())
    f = ds.frames
    pos = f.positions
    s1 = truth["sources"][0]
    s2 = truth["effects"]["second_source"]
    d1 = ((pos - np.array([s1["x"], s1["y"], s1["z"]])) ** 2).sum(1)
    d2 = ((pos - np.array([s2["x"], s2["y"], s2["z"]])) ** 2).sum(1)
    e = {"primary": s1["cps_at_1m"] / d1 * f.duration, "second": s2["cps_at_1m"] / d2 * f.duration,
         "background": ds.scenario.background_cps * f.duration}
    choice = identify_second_nuclide(f, np.asarray(ds.scenario.channel_edges_keV), ds.scenario.nuclide,
                                     e["primary"], e["second"], e["background"])
    assert choice.nuclide == "Cs-137", choice.note
    assert choice.gap / choice.dispersion > 100  # ~20k second-source counts: not a close call


@needs_spectra
def test_a_misplaced_count_fit_still_names_the_nuclide():
    # the count fit put the second source 1 m off and half as strong as it is: the expected counts per dwell
    # are wrong, the scales and the over-dispersion take it, the nuclide is still named
    f, e = flight("Cs-137", "Eu-152", 50.0, 7, model_offset_m=1.0, data_second_cps=100.0)
    choice = identify(f, e, "Cs-137")
    assert choice.nuclide == "Eu-152", choice.note


@needs_spectra
def test_a_primary_unknown_to_the_library_falls_back_to_the_nominal_crystal():
    f, e = flight("Cs-137", "Co-60", 300.0, 5)
    choice = identify_second_nuclide(f, EDGES, "Unobtainium", e["primary"], e["second"], e["background"],
                                     candidates=("Co-60", "Ba-133"))
    assert choice.nuclide == "Co-60" and "not fitted" in choice.note
    with pytest.raises(ValueError, match="unknown nuclide"):
        identify_second_nuclide(f, EDGES, "Cs-137", e["primary"], e["second"], e["background"],
                                candidates=("Co-60", "Xx-999"))


def test_crystal_attenuation_keeps_falling_above_xraydbs_tables():
    # xraydb's Elam tables stop at 800 keV (they return the 800 keV values above): the Compton part must follow
    # Klein-Nishina there and the photoelectric part keep falling, or Co-60's peaks come out 1.5x too strong
    from estimator.diagnose.nuclide import mu_crystal

    e = np.array([662.0, 800.0, 1173.0, 1332.0, 1461.0])
    ph, co = mu_crystal(e)
    assert np.all(np.diff(ph) < 0) and np.all(np.diff(co) < 0)
    assert co[3] / co[1] == pytest.approx(0.78, abs=0.02)  # Klein-Nishina sigma(1332) / sigma(800)
