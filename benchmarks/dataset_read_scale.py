"""Reading a large frames.csv: wall time and peak memory (issue 12 target: a 200 MB file in under 1 GB).

Generates a dataset of about ``--mb`` MB in /tmp by repeating the rows of a shared reference dataset
(``lattice-clean``; time and dwell indices shifted so rows stay in time order and dwells stay distinct),
then reads it in a fresh process and reports the wall time and the peak resident set size (ru_maxrss),
next to the RSS of that process after its imports (the floor every command pays). With ``--localize
METHOD`` the same child also runs ``radseek localize`` on it. Not a timed test: numbers depend on the
machine; run it by hand or through ``python -m benchmarks``.

    .venv/bin/python benchmarks/dataset_read_scale.py [--mb 200] [--localize sphere] [--keep] [--quick]
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks.shared_data import shared_path  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
SHARED = shared_path("datasets")

_CHILD = r"""
import json, resource, sys, time
sys.path.insert(0, {repo!r})
import numpy  # noqa: F401
from radseek_io import dataset
rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
t0 = time.perf_counter()
ds = dataset.read_dataset({path!r})
t_read = time.perf_counter() - t0
rss_read = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
out = {{"rows": len(ds.frames), "read_s": t_read, "rss_after_imports_mb": rss0 / 1024,
        "peak_rss_read_mb": rss_read / 1024}}
method = {method!r}
if method:
    from radseek_cli import localize_cli
    del ds
    t0 = time.perf_counter()
    rc = localize_cli.main([{path!r}, "--method", method, "--json"] + {extra!r})
    out["localize_rc"] = rc
    out["localize_s"] = time.perf_counter() - t0
    out["peak_rss_localize_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
print("RESULT " + json.dumps(out), file=sys.stderr)
"""


def make_dataset(target: Path, mb: float, source: Path = SHARED / "lattice-clean") -> tuple[int, int]:
    """Write ``target``/frames.csv of about ``mb`` MB and copy scenario.json. Returns (rows, bytes)."""
    target.mkdir(parents=True, exist_ok=True)
    shutil.copy(source / "scenario.json", target / "scenario.json")
    lines = (source / "frames.csv").read_text().splitlines()
    header, rows = lines[0], [r.split(",") for r in lines[1:] if r.strip()]
    t_span = float(rows[-1][0]) + 0.1
    n_dwell = max(int(r[9]) for r in rows) + 1
    limit = int(mb * 1e6)
    written, n = 0, 0
    with open(target / "frames.csv", "w") as fh:
        fh.write(header + "\n")
        written += len(header) + 1
        rep = 0
        while written < limit:
            chunk = []
            for r in rows:
                cells = list(r)
                cells[0] = f"{float(r[0]) + rep * t_span:.4f}"
                d = int(r[9])
                cells[9] = str(d + rep * n_dwell if d >= 0 else -1)
                chunk.append(",".join(cells))
            text = "\n".join(chunk) + "\n"
            fh.write(text)
            written += len(text)
            n += len(chunk)
            rep += 1
    return n, written


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--mb", type=float, default=200.0, help="size of the generated frames.csv (200)")
    p.add_argument("--quick", action="store_true", help="20 MB instead of --mb")
    p.add_argument("--localize", default="", metavar="METHOD", help="also run `radseek localize --method METHOD`")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="passed on to localize")
    p.add_argument("--keep", action="store_true", help="keep the generated dataset in /tmp")
    args = p.parse_args(argv)
    mb = 20.0 if args.quick else args.mb
    tmp = Path(tempfile.mkdtemp(prefix="radseek-scale-", dir="/tmp"))
    try:
        t0 = time.perf_counter()
        rows, size = make_dataset(tmp / "big", mb)
        print(f"generated {tmp / 'big'}: {rows} rows, {size / 1e6:.1f} MB in {time.perf_counter() - t0:.1f} s",
              flush=True)
        extra: list[str] = []
        for s in args.set:
            extra += ["--set", s]
        code = _CHILD.format(repo=str(REPO), path=str(tmp / "big"), method=args.localize, extra=extra)
        proc = subprocess.run([sys.executable, "-c", code], stderr=subprocess.PIPE, stdout=subprocess.DEVNULL,
                              text=True, cwd=REPO)
        result_lines = [ln for ln in proc.stderr.splitlines() if ln.startswith("RESULT ")]
        progress = [ln for ln in proc.stderr.splitlines() if not ln.startswith("RESULT ")]
        if not result_lines:
            print(proc.stderr[-4000:], file=sys.stderr)
            print(f"child failed (exit {proc.returncode})", file=sys.stderr)
            return 1
        res = json.loads(result_lines[-1].removeprefix("RESULT "))
        res.update({"file_mb": size / 1e6, "progress_lines": len(progress)})
        print(json.dumps(res, indent=2))
        print(f"read {res['rows']} rows ({size / 1e6:.0f} MB): {res['read_s']:.1f} s, peak RSS "
              f"{res['peak_rss_read_mb']:.0f} MB (after imports {res['rss_after_imports_mb']:.0f} MB); "
              f"{len(progress)} progress line(s) on stderr")
        if "localize_s" in res:
            print(f"localize --method {args.localize}: exit {res['localize_rc']}, {res['localize_s']:.1f} s, "
                  f"peak RSS {res['peak_rss_localize_mb']:.0f} MB")
        return 0
    finally:
        if args.keep:
            print(f"kept {tmp}")
        else:
            shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
