"""The shared reference data is found beside the clone, or where RADSEEK_SHARED says (a clone elsewhere)."""

import importlib

import benchmarks.shared_data as shared_data
from tests.conftest import REPO


def _resolved(monkeypatch, value: str | None) -> str:
    if value is None:
        monkeypatch.delenv("RADSEEK_SHARED", raising=False)
    else:
        monkeypatch.setenv("RADSEEK_SHARED", value)
    try:
        return str(importlib.reload(shared_data).shared_path("datasets", "lattice-clean"))
    finally:
        monkeypatch.undo()
        importlib.reload(shared_data)


def test_the_shared_folder_sits_beside_the_clone_unless_the_variable_names_another(monkeypatch, tmp_path):
    beside = str(REPO.parent / "shared" / "datasets" / "lattice-clean")
    assert _resolved(monkeypatch, None) == beside
    assert _resolved(monkeypatch, str(tmp_path)) == str(tmp_path / "datasets" / "lattice-clean")
    assert _resolved(monkeypatch, "") == beside  # set but empty counts as unset
