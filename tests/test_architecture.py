"""The import rules between packages, checked per package by parsing every module.

Layers, lowest first; a package imports only its own layer's packages and those below, as ``ALLOWED`` lists:

- ``radseek`` (the contracts: topics, board wire, frame record, dataset and truth types, coordinates) imports
  no other radseek package.
- ``radseek_io`` (files: dataset, truth.json, spectra, detector file, MCAP, output folders) imports only the
  contracts.
- The simulated world (``detector_fw_sim``, ``vehicle_sim``) and ``spectra`` import only the contracts, the
  I/O layer and themselves.
- The flight software (``mission``, ``estimator``, ``planner``) never imports the simulated world, the
  reports, the launchers or the command line, and never reads the truth: no import of the truth reader or of
  the ``Truth`` type, no ``.truth`` attribute, no ``"truth.json"`` string (docstrings aside).
- ``reporting`` (errors against the truth) sits above the flight software; ``launch`` and ``benchmarks``
  above that; ``radseek_cli`` (the ``radseek`` command) above everything, and nothing imports it.

Imports count wherever they are in a module (inside functions too) and in every form: absolute, relative
(``from . import x``, ``from ..x import y``, resolved to their package) and by name
(``importlib.import_module("x.y")``, ``__import__("x")``; a module that imports a computed name counts every
``"package.module"`` string it holds). No two packages import each other, directly or around a circle.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
CONTRACTS = {"radseek"}
IO = {"radseek_io"}
SIMULATOR = {"detector_fw_sim", "vehicle_sim"}
FLIGHT = {"mission", "estimator", "planner"}
REPORTING = {"reporting"}
LAUNCH = {"launch", "benchmarks"}
CLI = {"radseek_cli"}
OURS = CONTRACTS | IO | SIMULATOR | FLIGHT | REPORTING | LAUNCH | CLI | {"spectra"}

#: package -> the radseek packages it may import
ALLOWED = {
    "radseek": CONTRACTS,
    "radseek_io": CONTRACTS | IO,
    "detector_fw_sim": CONTRACTS | IO | SIMULATOR,
    "vehicle_sim": CONTRACTS | IO | SIMULATOR,
    "spectra": CONTRACTS | IO | SIMULATOR | {"spectra"},
    "mission": CONTRACTS | IO | FLIGHT,
    "estimator": CONTRACTS | IO | {"estimator"},
    "planner": CONTRACTS | IO | {"planner"},
    "reporting": CONTRACTS | IO | FLIGHT | REPORTING,
    "launch": OURS - CLI,
    "benchmarks": OURS - CLI,
    "radseek_cli": OURS,
}

#: what reads or holds the simulated truth: modules, and names imported from anywhere
TRUTH_MODULES = {"radseek.truth", "radseek_io.truth", "reporting.truth_errors"}
TRUTH_NAMES = {"Truth", "TruthSource", "read_truth", "read_dataset_with_truth"}

_IMPORT_FUNCS = {"import_module", "__import__"}
_MODULE_STRING = re.compile(r"^[A-Za-z_]\w*(\.[A-Za-z_]\w*)+$")


def module_package(path: Path, root: Path) -> list[str]:
    """The dotted package a module's relative imports start from (``a/b/c.py`` and ``a/b/__init__.py``: a.b)."""
    return list(path.relative_to(root).parent.parts)


def _resolve(relative: str, level: int, package: list[str]) -> str | None:
    """``from <level dots><relative> import ...`` in ``package``; None if it climbs above the top package."""
    if level - 1 >= len(package):
        return None
    base = package[: len(package) - (level - 1)]
    return ".".join([*base, relative] if relative else base)


def _call_name(node: ast.Call) -> str | None:
    f = node.func
    return f.id if isinstance(f, ast.Name) else f.attr if isinstance(f, ast.Attribute) else None


def imported_modules(path: Path, root: Path = REPO) -> set[str]:
    """Every module a file imports (dotted names), in every form; ``<above top>`` for a relative import that
    climbs out of the top package."""
    tree = ast.parse(path.read_text(), str(path))
    package = module_package(path, root)
    names: set[str] = set()
    computed = False
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            if node.level == 0:
                base = node.module or ""
            else:
                base = _resolve(node.module or "", node.level, package)
                if base is None:
                    names.add("<above top>")
                    continue
            names.add(base)
            names |= {f"{base}.{a.name}" for a in node.names}  # ``from pkg import module`` imports pkg.module
        elif isinstance(node, ast.Call) and _call_name(node) in _IMPORT_FUNCS and node.args:
            arg = node.args[0]
            if isinstance(arg, ast.Constant) and isinstance(arg.value, str):
                name = arg.value
                if name.startswith("."):
                    level = len(name) - len(name.lstrip("."))
                    resolved = _resolve(name.lstrip("."), level, package)
                    name = resolved if resolved is not None else "<above top>"
                names.add(name)
            else:
                computed = True
    if computed:  # a dispatch table of module names: every "pkg.module" string may be imported
        names |= {n.value for n in ast.walk(tree) if isinstance(n, ast.Constant) and isinstance(n.value, str)
                  and _MODULE_STRING.match(n.value) and n.value.split(".")[0] in OURS}
    return names


def imported_packages(path: Path, root: Path = REPO) -> set[str]:
    """Top-level radseek packages a module imports."""
    tops = {n.split(".")[0] for n in imported_modules(path, root)}
    return (tops & OURS) | (tops & {"<above top>"})


def modules(package: str, root: Path = REPO) -> list[Path]:
    return sorted((root / package).rglob("*.py"))


def violations(package: str, root: Path = REPO) -> list[str]:
    out = []
    for path in modules(package, root):
        bad = imported_packages(path, root) - ALLOWED[package]
        if bad:
            out.append(f"{path.relative_to(root)} imports {sorted(bad)}")
    return out


def _docstrings(tree: ast.AST) -> set[int]:
    ids = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant):
                ids.add(id(first.value))
    return ids


def truth_reads(package: str, root: Path = REPO) -> list[str]:
    """Where a package's modules reach the truth: a truth module or name imported, ``.truth`` read, or a
    ``"truth.json"`` string (docstrings aside)."""
    out = []
    for path in modules(package, root):
        rel = path.relative_to(root)
        tree = ast.parse(path.read_text(), str(path))
        found = sorted(m for m in imported_modules(path, root) if m in TRUTH_MODULES
                       or m.rsplit(".", 1)[-1] in TRUTH_NAMES)
        out += [f"{rel} imports {m}" for m in found]
        docs = _docstrings(tree)
        for node in ast.walk(tree):
            if isinstance(node, ast.Attribute) and node.attr == "truth":
                out.append(f"{rel}:{node.lineno} reads .truth")
            elif (isinstance(node, ast.Constant) and isinstance(node.value, str) and "truth.json" in node.value
                  and id(node) not in docs):
                out.append(f"{rel}:{node.lineno} names truth.json")
    return out


def package_graph(root: Path = REPO, packages=None) -> dict[str, set[str]]:
    """package -> the other packages it imports."""
    packages = sorted(ALLOWED) if packages is None else packages
    return {p: set().union(*(imported_packages(m, root) for m in modules(p, root))) - {p, "<above top>"}
            for p in packages}


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Import circles between packages (each once, starting from its smallest name)."""
    found = set()

    def walk(node: str, path: list[str]) -> None:
        for nxt in sorted(graph.get(node, ())):
            if nxt == path[0]:
                found.add(tuple(path))
            elif nxt not in path and nxt > path[0]:
                walk(nxt, [*path, nxt])

    for start in sorted(graph):
        walk(start, [start])
    return [[*c, c[0]] for c in sorted(found)]


# ------------------------------------------------------------------------------------------------ the rules


@pytest.mark.parametrize("package", sorted(ALLOWED))
def test_package_imports_only_what_its_layer_allows(package):
    assert (REPO / package / "__init__.py").exists(), f"{package} is not a package"
    assert violations(package) == []


def test_every_top_level_package_has_a_rule():
    packages = {p.parent.name for p in REPO.glob("*/__init__.py")} - {"tests"}
    assert packages == set(ALLOWED)


def test_no_import_cycles_between_packages():
    assert cycles(package_graph()) == []


def test_nothing_but_tests_imports_the_command_line():
    assert [p for p, deps in package_graph().items() if deps & CLI and p not in CLI] == []


@pytest.mark.parametrize("package", sorted(FLIGHT))
def test_flight_software_never_reads_the_truth(package):
    assert truth_reads(package) == []


def test_the_contracts_hold_one_spectrum_class():
    defs = [f"{p.relative_to(REPO)}" for pkg in ALLOWED for p in modules(pkg)
            if any(isinstance(n, ast.ClassDef) and n.name == "Spectrum" for n in ast.walk(ast.parse(p.read_text())))]
    assert defs == ["radseek/spectrum.py"]


# ------------------------------------------------------------------------------------------------ the checker


def _fake(tmp_path: Path, package: str, source: str, name: str = "sneaky.py") -> None:
    d = tmp_path / package
    d.mkdir(parents=True, exist_ok=True)
    (d / "__init__.py").touch()
    (d / name).write_text(source)


def test_the_rule_catches_a_simulator_import(tmp_path):
    # the checker itself: a flight-software module that imports the simulator is reported
    _fake(tmp_path, "mission", "def f():\n    from vehicle_sim.odometry import Odometry\n")
    assert violations("mission", tmp_path) == ["mission/sneaky.py imports ['vehicle_sim']"]


@pytest.mark.parametrize("source, package, bad", [
    ("import launch.run_team\n", "estimator", "launch"),
    ("from radseek_cli import main\n", "launch", "radseek_cli"),
    ("import radseek_io.dataset\n", "radseek", "radseek_io"),
    ("from reporting.truth_errors import match_errors\n", "estimator", "reporting"),
])
def test_the_rule_catches_an_absolute_import_across_layers(tmp_path, source, package, bad):
    _fake(tmp_path, package, source)
    assert violations(package, tmp_path) == [f"{package}/sneaky.py imports ['{bad}']"]


def test_the_rule_resolves_relative_imports_to_their_package(tmp_path):
    # ``from .. import`` from a subpackage stays inside the package; climbing above it is reported
    _fake(tmp_path, "estimator/sub", "from .. import model\nfrom ..diagnose import runner\nfrom . import x\n")
    assert violations("estimator", tmp_path) == []
    assert imported_modules(tmp_path / "estimator/sub/sneaky.py", tmp_path) >= {"estimator", "estimator.diagnose",
                                                                                 "estimator.sub.x"}
    _fake(tmp_path, "estimator/sub", "from ... import vehicle_sim\n", "climb.py")
    assert violations("estimator", tmp_path) == ["estimator/sub/climb.py imports ['<above top>']"]


@pytest.mark.parametrize("source", [
    "import importlib\nm = importlib.import_module('vehicle_sim.vehicle')\n",
    "from importlib import import_module\nm = import_module('vehicle_sim')\n",
    "m = __import__('vehicle_sim.vehicle')\n",
    "import importlib\nCMDS = {'v': 'vehicle_sim.vehicle'}\nm = importlib.import_module(CMDS['v'])\n",
])
def test_the_rule_catches_string_imports(tmp_path, source):
    _fake(tmp_path, "mission", source)
    assert violations("mission", tmp_path) == ["mission/sneaky.py imports ['vehicle_sim']"]


def test_the_rule_catches_an_import_circle(tmp_path):
    _fake(tmp_path, "launch", "import benchmarks.x\n")
    _fake(tmp_path, "benchmarks", "def f():\n    from launch import stack\n")
    assert cycles(package_graph(tmp_path, ["benchmarks", "launch"])) == [["benchmarks", "launch", "benchmarks"]]
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c", "a"]]


@pytest.mark.parametrize("source, found", [
    ("from radseek.truth import Truth\n", "estimator/sneaky.py imports radseek.truth"),
    ("from radseek.dataset import Dataset, Truth\n", "estimator/sneaky.py imports radseek.dataset.Truth"),
    ("def f(p):\n    from radseek_io.truth import read_dataset_with_truth\n",
     "estimator/sneaky.py imports radseek_io.truth"),
    ("from radseek_io import truth\n", "estimator/sneaky.py imports radseek_io.truth"),
    ("def f(ds):\n    return ds.truth\n", "estimator/sneaky.py:2 reads .truth"),
    ("from pathlib import Path\nP = Path('x') / 'truth.json'\n", "estimator/sneaky.py:2 names truth.json"),
])
def test_the_rule_catches_the_flight_software_reading_the_truth(tmp_path, source, found):
    _fake(tmp_path, "estimator", source)
    assert found in truth_reads("estimator", tmp_path)


def test_a_docstring_may_name_truth_json(tmp_path):
    _fake(tmp_path, "estimator", '"""Never reads truth.json."""\n\n\ndef f():\n    """Nor here: truth.json."""\n')
    assert truth_reads("estimator", tmp_path) == []
