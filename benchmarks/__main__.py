"""Run every benchmark script in this folder: ``.venv/bin/python -m benchmarks [--quick] [NAME ...]``.

Each ``benchmarks/<name>.py`` runs as its own process with its default arguments (``--quick`` is passed
on to scripts whose ``--help`` mentions it). Prints each script's output and a summary of exit codes.
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent


def scripts() -> list[Path]:
    return sorted(p for p in HERE.glob("*.py") if not p.name.startswith("_"))


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    quick = "--quick" in argv
    names = [a for a in argv if not a.startswith("-")]
    todo = [p for p in scripts() if not names or p.stem in names]
    results = []
    for path in todo:
        cmd = [sys.executable, str(path)]
        if quick:
            helptext = subprocess.run(cmd + ["--help"], capture_output=True, text=True, cwd=HERE.parent).stdout
            if "--quick" in helptext:
                cmd.append("--quick")
        print(f"=== {path.name}: {' '.join(cmd[1:])}", flush=True)
        t0 = time.perf_counter()
        rc = subprocess.run(cmd, cwd=HERE.parent).returncode
        results.append((path.name, rc, time.perf_counter() - t0))
    print("\n=== summary")
    for name, rc, dt in results:
        print(f"{name:32s} {'ok' if rc == 0 else f'FAILED ({rc})':12s} {dt:8.1f} s")
    return 0 if all(rc == 0 for _, rc, _ in results) else 1


if __name__ == "__main__":
    sys.exit(main())
