"""calibrate on a spectrum without a background: windows where the model expects nothing say so in counts."""

import json
import math

from radseek_cli.calibrate_cli import main
from tests.conftest import REPO

AM241 = REPO.parent / "shared" / "real-spectra" / "data_am241.n42"
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
