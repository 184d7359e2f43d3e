"""Bare commands write under runs/ (git-ignored), never beside the user's own files in the current folder."""

import argparse
import os
import subprocess
import sys
from pathlib import Path

import pytest

from radseek_cli.compare_cli import _build_parser as compare_parser
from radseek_cli.compare_cli import plot_path
from radseek_cli.plan_cli import _parser as plan_parser
from radseek_cli.simulate_cli import build_parser as simulate_parser

REPO = Path(__file__).resolve().parents[1]


def _default_out(p: argparse.ArgumentParser) -> str:
    return str(next(a.default for a in p._actions if "--out" in a.option_strings))


def test_every_default_output_is_under_runs():
    assert _default_out(simulate_parser()).startswith("runs/")
    assert _default_out(compare_parser()).startswith("runs/")
    from radseek_cli.diagnose_cli import default_out

    a, b = default_out(Path("/x/run1/dataset")), default_out(Path("/x/run2/dataset"))
    assert a.parts[0] == "runs" and a.name.startswith("diagnose-dataset-") and a != b
    assert default_out(Path("/x/run1/dataset")) == a
    assert 'Path("runs/flight.mcap")' in (REPO / "radseek_cli" / "record_cli.py").read_text()
    assert "runs/" in (REPO / ".gitignore").read_text().split()
    fig4 = next(a for a in plan_parser()._actions if "--fig4" in a.option_strings)
    assert str(fig4.const).startswith("runs/")  # `radseek plan --fig4` wrote fig4-replica.png into the cwd


def test_compare_names_the_file_it_writes(tmp_path):
    """`compare --out /tmp/cmp` wrote /tmp/cmp.png (matplotlib adds the suffix) but said "wrote /tmp/cmp"."""
    assert plot_path(tmp_path / "cmp") == tmp_path / "cmp.png"
    assert plot_path(tmp_path / "cmp.pdf") == tmp_path / "cmp.pdf"
    assert plot_path(tmp_path) == tmp_path / "compare.png"  # a folder: the default name inside it


@pytest.mark.io
def test_bare_simulate_dataset_writes_only_under_runs(tmp_path):
    r = subprocess.run([sys.executable, "-m", "radseek_cli", "simulate-dataset"], cwd=tmp_path, capture_output=True,
                       text=True, timeout=300, env={**os.environ, "PYTHONPATH": str(REPO)})
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["runs"]
    assert (tmp_path / "runs" / "simulated-dataset" / "frames.csv").is_file()
