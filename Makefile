# The commands a new user needs: `make run` (a search mission against the mock vehicle)
# and `make test` (the whole test suite, what CI runs: every test, in 4 parallel pytest-xdist workers on 2 cores,
# as many tests wait on sockets, subprocesses and sped-up clocks: 4:48-5:42 over six clean-clone runs on 2 idle cores
# of 2026-12-07's host (414-492 s of user CPU; lattice-wall's diagnose 9.2 s there), 7:32-8:50 over eight on 2026-12-06's
# slower host (the same diagnose 15.1 s; that shared host slowed down through them: one diagnose took 21.7 s of CPU
# alone, 24.8 s two hours later, and 23-31 s inside the runs), 8:02 at the previous session's end with 4 workers in the planned order
# (8:33 and 9:24 with 4 and 3 in the old order). 5 workers took 7:38 once, but starved the security tests' runs:
# a compromised board's copies of the detector's frames overtook the originals (the documented copy race) and a
# run failed; not kept); handed one test at a time in the order tests/support/schedule.py plans from tests/durations.json,
# longest first; tests taking the same fixed port are marked `exclusive` and never overlap; `make durations`
# re-measures the durations after tests are added or made faster).
# `make check` is the edit-test loop's unit tier (39-45 s on 2 idle cores, 2026-12-07; 64-77 s on 2026-12-06's host): lint plus every test
# that is neither `slow` nor `io` (no subprocess, socket, zenoh session or router; --unit fails a test that opens one).
# All create .venv and install radseek on first use.
# The tests run with Python's byte-code cache on (PYTHONDONTWRITEBYTECODE unset, where a machine sets it, as this
# project's CI machines do): every worker and every process a test starts otherwise compiles radseek's modules and
# pytest rewrites every test module again (collection 8.9 -> 3.7 s of CPU per worker; __pycache__ is git-ignored).
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
# One BLAS thread per process: 4 workers (and the processes their tests start) on 2 cores each with OpenBLAS's pool of
# 2 threads oversubscribe the cores; one diagnose, three at once, took 7 % less CPU with one thread (23.8 -> 22.1 s).
PYTEST := env -u PYTHONDONTWRITEBYTECODE OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 $(BIN)/pytest
STAMP := $(VENV)/.installed
# MAVSDK-Python's examples use the gRPC API (`from mavsdk import System`): `mavsdk<4` (3.x, bundling
# mavsdk_server), whose import name collides with radseek's native `mavsdk` 4.x, so they get their own venv.
GRPC_VENV := .venv-mavsdk-grpc
GRPC_STAMP := $(GRPC_VENV)/.installed

.PHONY: run test durations check lint bench clean

$(STAMP): pyproject.toml
	$(PY) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[dev]'
	# MAVProxy only for the interoperability test: its GUI dependencies are ~1.3 GB, so no deps.
	$(BIN)/pip install --quiet --no-deps mavproxy pyserial
	touch $(STAMP)

$(GRPC_STAMP):
	$(PY) -m venv $(GRPC_VENV)
	$(GRPC_VENV)/bin/pip install --quiet 'mavsdk>=3.15,<4' anyio tqdm  # as tests/test_mavsdk_examples.py's GRPC_VENV_PACKAGES
	touch $(GRPC_STAMP)

run: $(STAMP)
	$(BIN)/radseek run

test: $(STAMP) $(GRPC_STAMP)
	$(BIN)/ruff check .
	$(PYTEST) -q -n 4 --maxschedchunk 1

durations: $(STAMP) $(GRPC_STAMP)
	$(PYTEST) -q -n 4 --maxschedchunk 1 --record-durations tests/durations.json

check: $(STAMP)
	$(BIN)/ruff check .
	$(PYTEST) -q -n 2 --maxschedchunk 1 -m "not slow and not io" --unit

lint: $(STAMP)
	$(BIN)/ruff check .

bench: $(STAMP)
	$(BIN)/python -m benchmarks

clean:
	rm -rf $(VENV) $(GRPC_VENV) runs
