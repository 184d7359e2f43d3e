"""docs/px4-parity.md, the table of MAVSDK-Python's examples against the vehicle, checked against the examples and
the tests: every example vendored in tests/mavsdk_upstream/ and every one in ../shared/mavsdk-python-examples has a
row (and every one of a checkout named by RADSEEK_MAVSDK_PYTHON_EXAMPLES), each named test exists and runs that
example, a row without a test says it was run by hand, and the summary's counts are the table's. Files only."""

import ast
import os
import re
from pathlib import Path

import pytest

from benchmarks.shared_data import shared_path

REPO = Path(__file__).resolve().parents[1]
DOC = REPO / "docs" / "px4-parity.md"
VENDORED = REPO / "tests" / "mavsdk_upstream"
SHARED = shared_path("mavsdk-python-examples")


def rows() -> list[dict[str, str]]:
    out = []
    for line in DOC.read_text().splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) == 4 and cells[0].startswith("`") and cells[0].endswith(".py`"):
            out.append(dict(zip(("example", "result", "why", "test"), cells, strict=True)))
    return out


def scripts(folder: Path) -> set[str]:
    return {p.relative_to(folder).as_posix() for p in folder.rglob("*.py")}


def test_every_example_has_one_row():
    listed = [r["example"].strip("`") for r in rows()]
    assert len(listed) == len(set(listed)), "an example listed twice"
    assert scripts(VENDORED) <= set(listed), scripts(VENDORED) - set(listed)
    if SHARED.is_dir():
        assert scripts(SHARED) <= set(listed), scripts(SHARED) - set(listed)
    checkout = os.environ.get("RADSEEK_MAVSDK_PYTHON_EXAMPLES")
    if checkout:  # a whole upstream examples/ folder: exactly its scripts
        assert set(listed) == scripts(Path(checkout))
    assert len(listed) == int(re.search(r"(\d+) scripts", DOC.read_text()).group(1))


def test_the_summary_counts_are_the_tables():
    results = [r["result"] for r in rows()]
    text = " ".join(DOC.read_text().split())
    counts = {"pass": sum(r.startswith("passes") for r in results), "wait": sum(r.startswith("waits") for r in results),
              "fail": sum(r.startswith("fails") for r in results)}
    assert sum(counts.values()) == len(results), "a result that is neither passes, waits nor fails"
    assert f"**{counts['pass']} pass**" in text and f"**{counts['wait']} waits**" in text
    assert f"**{counts['fail']} fail**" in text


def _functions(path: Path) -> dict[str, str]:
    """test name -> its source with its decorators (a parametrized test names its examples there)."""
    source = path.read_text()
    tree = ast.parse(source)
    out = {}
    for node in tree.body:
        if isinstance(node, ast.FunctionDef):
            parts = [ast.get_source_segment(source, d) or "" for d in node.decorator_list]
            out[node.name] = "\n".join([*parts, ast.get_source_segment(source, node) or ""])
    return out


@pytest.mark.parametrize("row", rows(), ids=lambda r: r["example"].strip("`"))
def test_each_named_test_runs_its_example(row):
    cell = row["test"]
    named = re.fullmatch(r"`(tests/[\w/]+\.py)::(\w+)`", cell)
    if named is None:
        assert cell.startswith("run by hand"), f"{row['example']}: test cell {cell!r} names no test"
        return
    path, name = REPO / named.group(1), named.group(2)
    functions = _functions(path)
    assert name in functions, f"{row['example']}: {name} not in {path.name}"
    assert row["example"].strip("`").rsplit("/", 1)[-1] in functions[name], f"{name} does not run {row['example']}"
