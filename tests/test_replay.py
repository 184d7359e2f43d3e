"""radseek replay: the estimate after each dwell of a recorded flight, as the mission had it in the air."""

import json
import subprocess
import sys

from estimator.replay_cli import replay
from radseek.dataset import read_dataset


def test_replay_converges_on_the_reference_lattice(shared_datasets):
    rows = replay(read_dataset(shared_datasets / "lattice-clean"), "mle", {"n_starts": 2})
    assert [r["dwells"] for r in rows] == list(range(1, 10))
    # more dwells, more information: the final ellipse is tighter than after four dwells, and the final
    # error lies within 4 of its own sigmas (plus the ~4 cm per-dwell pose offset of the reference data)
    assert rows[-1]["sigma_m"] < rows[3]["sigma_m"]
    assert rows[-1]["error_m"] < 4 * rows[-1]["sigma_m"] + 0.04


def test_replay_cli_json_and_bad_input(shared_datasets, tmp_path):
    out = subprocess.run([sys.executable, "-m", "radseek.cli", "replay", str(shared_datasets / "lattice-clean"),
                          "--method", "sphere", "--json", "--plot", str(tmp_path / "r.png")],
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    rows = json.loads(out.stdout)
    assert rows[-1]["dwells"] == 9 and (tmp_path / "r.png").stat().st_size > 1000
    bad = subprocess.run([sys.executable, "-m", "radseek.cli", "replay", str(tmp_path / "nope")],
                         capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "not a dataset directory" in bad.stderr
