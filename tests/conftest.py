"""Shared fixtures: the shared reference datasets live beside the repository (../shared/datasets)."""

from __future__ import annotations

from pathlib import Path

import pytest

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
