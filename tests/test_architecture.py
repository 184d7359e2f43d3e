"""The import rules between packages, checked per package by parsing every module.

- ``radseek`` (the contracts) imports no other radseek package.
- The simulated world (``detector_fw_sim``, ``vehicle_sim``) imports only the contracts and itself.
- The flight software (``mission``, ``estimator``, ``planner``) never imports the simulated world or the
  launchers; only ``launch``, ``benchmarks`` and ``tests`` may see the truth.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
CONTRACTS = {"radseek"}
SIMULATOR = {"detector_fw_sim", "vehicle_sim"}
FLIGHT = {"mission", "estimator", "planner"}
LAUNCH = {"launch", "benchmarks"}
OURS = CONTRACTS | SIMULATOR | FLIGHT | LAUNCH | {"spectra"}

#: package -> the radseek packages it may import
ALLOWED = {
    "radseek": CONTRACTS,
    "detector_fw_sim": CONTRACTS | SIMULATOR,
    "vehicle_sim": CONTRACTS | SIMULATOR,
    "mission": CONTRACTS | FLIGHT,
    "estimator": CONTRACTS | {"estimator"},
    "planner": CONTRACTS | {"planner"},
    "launch": OURS,
    "benchmarks": OURS,
    "spectra": CONTRACTS | SIMULATOR | {"spectra"},
}


def imported_packages(path: Path) -> set[str]:
    """Top-level radseek packages a module imports (absolute imports, anywhere in the module)."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module.split(".")[0])
    return names & OURS


def violations(package: str, root: Path = REPO) -> list[str]:
    out = []
    for path in sorted((root / package).rglob("*.py")):
        bad = imported_packages(path) - ALLOWED[package]
        if bad:
            out.append(f"{path.relative_to(root)} imports {sorted(bad)}")
    return out


@pytest.mark.parametrize("package", sorted(ALLOWED))
def test_package_imports_only_what_its_layer_allows(package):
    assert (REPO / package / "__init__.py").exists(), f"{package} is not a package"
    assert violations(package) == []


def test_every_top_level_package_has_a_rule():
    packages = {p.parent.name for p in REPO.glob("*/__init__.py")} - {"tests"}
    assert packages == set(ALLOWED)


def test_the_rule_catches_a_simulator_import(tmp_path):
    # the checker itself: a flight-software module that imports the simulator is reported
    fake = tmp_path / "mission"
    fake.mkdir()
    (fake / "__init__.py").write_text("")
    (fake / "sneaky.py").write_text("def f():\n    from vehicle_sim.odometry import Odometry\n")
    assert violations("mission", tmp_path) == ["mission/sneaky.py imports ['vehicle_sim']"]
