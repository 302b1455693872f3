# Two commands a new user needs: `make run` and `make test`.
# Both create the virtual environment .venv on first use (Python >= 3.11 + pip only).
# Developers: `make lint` (ruff, mypy), `make test-fast` (the suite without the slow tier).

PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed-stamp
OUT    ?= out/paper_case1

.PHONY: run test test-fast lint bench venv clean

venv: $(STAMP)

$(STAMP): pyproject.toml
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	@# (setuptools tells every editable install of a package at the checkout's top to beware of a
	@# folder of the package's name in the working directory: here that folder is the package)
	PYTHONWARNINGS='ignore:Editable installation' $(BIN)/python -m pip install --quiet -e '.[dev]'
	@touch $(STAMP)

run: $(STAMP)
	$(BIN)/dkfsim run scenarios/paper_case1.yaml --out $(OUT)

# ruff (pyflakes, import order, bugbear, unused arguments) and mypy against its baseline
# (pyproject.toml, [tool.ruff] and [tool.mypy]); the pre-commit hooks run the same.
lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/python tools/mypy_baseline.py

# Lint first, then every test, one test process per CPU (pytest-xdist): the suite is many
# independent small simulations, handed out by work stealing (a worker that runs out takes half
# of the other's queue: no idle core while the last long tests run).  .ci/run runs this.
test: lint
	$(BIN)/python -m pytest -n auto --dist worksteal

# Everything but the tests marked slow (end-to-end commands, Dask, the notebook, fuzzing,
# killed processes, scale, every test over 1.5 s: tests/slow_tests.txt): under 90 s on 2 cores.
test-fast: $(STAMP)
	$(BIN)/python -m pytest -n auto --dist worksteal -m "not slow"

bench: $(STAMP)
	$(BIN)/python tools/bench.py

clean:
	rm -rf out .pytest_cache .hypothesis .mypy_cache .ruff_cache
