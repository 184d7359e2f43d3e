"""A real walk becomes a flight (issue 32 item 4): radiacode-tools' NDJSON log of RC-103-000070 with GNSS fixes
(tests/data/real-spectra/walk_rc103_gnss.ndjson, MIT; its origin in that folder's README) imported with
``radseek spectra import-flight``, then ``radseek localize`` and ``radseek diagnose`` on it. The walk has no
source: both must say so plainly, and neither may crash on the log's timing, as recorded (a device reset, a 587 s
logger gap) or made irregular by dropping spectrum records (the same real records, polled at uneven intervals)."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from estimator.diagnose.verdict import SOURCE_SIGMA, source_reading
from radseek_cli import diagnose_cli, flight_cli, localize_cli
from radseek_io.dataset import read_dataset

REPO = Path(__file__).resolve().parent.parent
WALK = REPO / "tests" / "data" / "real-spectra" / "walk_rc103_gnss.ndjson"
PLAIN = "no source above background"


def _run(capsys, command: str, *args) -> SimpleNamespace:
    """``radseek COMMAND ARGS`` in this process, as the command line runs it (its exit code, stdout and stderr): the
    answers are the command's, not the process boundary's (a subprocess each cost ~1.3 s of start-up CPU)."""
    main = {"localize": localize_cli.main, "diagnose": diagnose_cli.main}[command]
    capsys.readouterr()
    code = main([*map(str, args)])
    out, err = capsys.readouterr()
    return SimpleNamespace(returncode=code, stdout=out, stderr=err)


def _thinned(tmp_path: Path, keep: float, seed: int) -> Path:
    """The real log with each spectrum record after the first kept with probability ``keep`` (seeded), every
    GNSS fix and device record kept: the cumulative spectra are the device's own, only polled unevenly."""
    rng = np.random.default_rng(seed)
    out, first = [], True
    for line in WALK.read_text().splitlines():
        if '"counts"' in line and not first and rng.random() > keep:
            continue
        first = first and '"counts"' not in line
        out.append(line)
    p = tmp_path / "walk_uneven.ndjson"
    p.write_text("\n".join(out) + "\n")
    return p


def _import(log: Path, out: Path):
    assert flight_cli.main(["import-flight", str(log), "--out", str(out)]) == 0
    return read_dataset(out).frames


def _check_answers(capsys, ds: Path, tmp_path: Path) -> None:
    r = _run(capsys, "localize", ds)
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    assert "source 1" in r.stdout and PLAIN in r.stdout, r.stdout
    r = _run(capsys, "diagnose", ds, "--no-plots", "--starts", "2", "--jobs", "1", "--quiet", "--out",
             tmp_path / "diag")
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    assert PLAIN in r.stdout and "Verdict:" in r.stdout, r.stdout


@pytest.mark.slow
def test_real_walk_localize_and_diagnose_say_no_source(tmp_path, capsys):
    f = _import(WALK, tmp_path / "walk")
    assert len(f) == 80
    _check_answers(capsys, tmp_path / "walk", tmp_path)


@pytest.mark.slow
def test_unevenly_polled_walk_imports_and_answers(tmp_path, capsys):
    full = _import(WALK, tmp_path / "walk")
    f = _import(_thinned(tmp_path, 0.7, seed=3), tmp_path / "uneven")
    d = np.asarray(f.duration)
    # irregular: frames of one to four 5 s polls, each its own live time (54 frames)
    assert 50 <= len(f) < len(full) and d.min() > 4.5 and len(np.unique(np.round(d / 5))) >= 3
    assert np.all(np.diff(f.t) > 0)
    # the counts are the device's: thinning merges frames, it cannot make counts
    assert 0 < f.counts.sum() <= full.counts.sum()
    _check_answers(capsys, tmp_path / "uneven", tmp_path)


def test_too_sparse_a_walk_is_refused_by_diagnose_in_one_line(tmp_path, capsys):
    """Polled at under half the records (35 frames of 5-35 s), diagnose says it needs 50 frames, plainly;
    localize still answers."""
    f = _import(_thinned(tmp_path, 0.45, seed=3), tmp_path / "sparse")
    assert len(f) == 35 and np.asarray(f.duration).max() > 6 * np.asarray(f.duration).min()
    r = _run(capsys, "diagnose", tmp_path / "sparse", "--no-plots", "--quiet")
    assert r.returncode == 2 and "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1
    assert "only 35 usable frames" in r.stderr and "50" in r.stderr
    r = _run(capsys, "localize", tmp_path / "sparse")
    assert r.returncode == 0 and PLAIN in r.stdout, r.stderr

def test_a_source_is_named_only_above_three_standard_errors():
    """The plain line both commands print: the diagnose fit of the real walk (2 starts) gave 19.1 +- 9.4 cps at 1 m,
    2.0 standard errors: not a source. One at 3.5 errors is; no finite error is never a source."""
    assert SOURCE_SIGMA == 3.0
    assert PLAIN in source_reading(19.1, 9.4)
    assert PLAIN in source_reading(4.8, 18.0)
    assert source_reading(35.0, 10.0) is None and source_reading(3.0e4, 40.0) is None
    assert PLAIN in source_reading(50.0, None) and PLAIN in source_reading(50.0, float("nan"))
    assert PLAIN in source_reading(29.9, 10.0)
