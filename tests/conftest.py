"""Shared fixtures: the shared reference datasets live beside the repository (../shared/datasets)."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import settings

# CI is deterministic: every property test draws the same examples on every run (a fuzz test that found a
# new case at random once in a while would block every landing). To explore beyond them, run
# HYPOTHESIS_PROFILE=explore pytest tests/test_fuzz_*.py (new random draws on every run).
settings.register_profile("ci", derandomize=True, database=None)
settings.register_profile("explore", derandomize=False, database=None)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))

REPO = Path(__file__).resolve().parents[1]
SHARED_DATASETS = REPO.parent / "shared" / "datasets"


def shared_dataset_names() -> list[str]:
    if not SHARED_DATASETS.is_dir():
        return []
    return sorted(p.name for p in SHARED_DATASETS.iterdir() if (p / "frames.csv").exists())


@pytest.fixture(scope="session")
def shared_datasets() -> Path:
    if not SHARED_DATASETS.is_dir():
        pytest.fail(f"shared datasets not found at {SHARED_DATASETS}: clone next to shared/")
    return SHARED_DATASETS


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def router():
    """A real `radseek router` on a free loopback port; yields its endpoint."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    proc = subprocess.Popen([sys.executable, "-m", "radseek.cli", "router", "--listen", endpoint],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        assert "listening" in proc.stdout.readline()
        yield endpoint
    finally:
        proc.terminate()
        try:  # a wait bound only (a loaded host may be slow to shut it down); never leave it running
            proc.wait(60)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


@pytest.fixture
def counted_fits(monkeypatch):
    """Count the in-flight estimator's fits by their ``n_starts`` (``calls``), and, while ``misfit["on"]``,
    inject the fault of a failed goodness of fit (p = 1e-6) into each fit's result."""
    from estimator.inflight import InflightEstimator

    real_fit = InflightEstimator._fit
    calls: list[int | None] = []
    misfit = {"on": False}

    def fit(self, frames, settings):
        loc = real_fit(self, frames, settings)
        calls.append(settings.get("n_starts"))
        if misfit["on"] and loc is not None:
            loc.info_["p_value"] = 1e-6
        return loc

    monkeypatch.setattr(InflightEstimator, "_fit", fit)
    return calls, misfit
