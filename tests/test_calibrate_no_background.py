"""calibrate on a spectrum without a background: windows where the model expects nothing say so in counts."""

import json
import math

from benchmarks.shared_data import shared_path
from radseek_cli.calibrate_cli import main
from tests.conftest import REPO

AM241 = shared_path("real-spectra", "data_am241.n42")
#: the RC-102's joint response (benchmarks/real_spectra.py), evaluated with no refit: the windows are the test
DETECTOR = REPO / "docs" / "img" / "rc102-001272.joint.detector.json"


def test_am241_without_background_gives_counts_not_absurd_percentages(capsys):
    args = [str(AM241), "--nuclide", "Am-241", "--no-fit", "--detector", str(DETECTOR)]
    assert main([*args, "--json"]) == 0
    out = json.loads(capsys.readouterr().out, parse_constant=lambda c: (_ for _ in ()).throw(ValueError(c)))
    windows = [w for w in out["still_missing"] if "from_keV" in w]
    assert windows
    for w in windows:
        if w["model_counts"] < 1.0:
            assert w["relative"] is None  # no ratio to a model expecting nothing
        else:
            assert math.isfinite(w["relative"]) and abs(w["relative"]) < 1e3
    # the Am-241 response has no lines above 100 keV: the room background there is counts the model lacks
    assert any(w["relative"] is None and w["from_keV"] > 150 for w in windows)
    assert main(args) == 0
    text = capsys.readouterr().out
    assert "counts where the model expects" in text and "0000" not in text.split("still missing")[1][:400]


def test_the_plot_shows_every_window_the_text_names(tmp_path, capsys, monkeypatch):
    """Issue 35: the calibration plot stopped at 1 MeV while the text named 1.7-2.1 MeV as missing. The energy
    axis of the saved figure reaches the top of every still-missing window the JSON (and the text) names."""
    import matplotlib.figure

    seen = []
    real_savefig = matplotlib.figure.Figure.savefig

    def spy(fig, *a, **kw):  # records what the saved figure shows; the file is still written
        seen.append([ax.get_xlim() for ax in fig.axes])
        return real_savefig(fig, *a, **kw)

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", spy)
    png = tmp_path / "cs137.png"
    spectra = AM241.parent
    args = [str(spectra / "Cs137_b.xml"), "--nuclide", "Cs-137", "--background", str(spectra / "bg.xml"), "--no-fit",
            "--detector", str(DETECTOR), "--plot", str(png)]
    assert main([*args, "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    windows = [w for w in out["still_missing"] if "from_keV" in w]
    assert windows and png.stat().st_size > 10_000 and len(seen) == 1
    spectrum_axis, residual_axis = seen[0][0], seen[0][1]
    top = max(w["to_keV"] for w in windows)
    assert top > 1500  # the case: a window far above the photopeak (1.7-2.1 MeV)
    assert spectrum_axis[1] >= top and residual_axis == spectrum_axis, (spectrum_axis, top)
