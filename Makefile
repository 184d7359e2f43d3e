# The two commands a new user needs: `make run` (a search mission against the mock vehicle)
# and `make test` (the whole test suite). Both create .venv and install radseek on first use.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: run test lint bench clean

$(STAMP): pyproject.toml
	$(PY) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[dev]'
	# MAVProxy only for the interoperability test: its GUI dependencies are ~1.3 GB, so no deps.
	$(BIN)/pip install --quiet --no-deps mavproxy pyserial
	touch $(STAMP)

run: $(STAMP)
	$(BIN)/radseek run

test: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/pytest -q

lint: $(STAMP)
	$(BIN)/ruff check .

bench: $(STAMP)
	$(BIN)/python -m benchmarks

clean:
	rm -rf $(VENV) runs
