# Two commands a new user needs: `make run` and `make test`.
# Both create the virtual environment .venv on first use (Python >= 3.11 + pip only).

PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed-stamp
OUT    ?= out/paper_case1

.PHONY: run test bench venv clean

venv: $(STAMP)

$(STAMP): pyproject.toml
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	@touch $(STAMP)

run: $(STAMP)
	$(BIN)/dkfsim run scenarios/paper_case1.yaml --out $(OUT)

# One test process per CPU (pytest-xdist): the suite is many independent small simulations.
test: $(STAMP)
	$(BIN)/python -m pytest -n auto

bench: $(STAMP)
	$(BIN)/python tools/bench.py

clean:
	rm -rf out .pytest_cache .hypothesis
