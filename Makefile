# encons — common tasks. `make install` once, then `make test`.
PY      ?= python3
VENV    ?= .venv
BIN     := $(VENV)/bin
ARGS    ?=

.PHONY: install lint test test-fast train bench benchmark report clean

install:  ## fresh virtual environment: CPU torch first (pinned), then encons with its dev extra
	$(PY) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q torch==2.13.0
	$(BIN)/pip install -q -e ".[dev]"

lint:  ## ruff (lint and format check) on the package, its tests and benchmarks, and mypy on encons/ ([tool.ruff], [tool.mypy]); what CI runs first
	$(BIN)/ruff check encons tests benchmarks && $(BIN)/ruff format --check encons tests benchmarks && $(BIN)/mypy

test:  ## every test, fast tier and the end-to-end, DDP, PostgreSQL and wheel tests (marked slow), on all cores; what CI runs
	$(BIN)/python -m pytest -n auto --dist worksteal

test-fast:  ## unit and physics tests only, on all cores
	$(BIN)/python -m pytest -n auto --dist worksteal -m "not slow"

train:  ## e.g. make train ARGS="model=chnn system=gyroscope"
	$(BIN)/python -m encons.train $(ARGS)

bench:  ## speed per model (steps/s, peak memory, × floor, × naive), dataset generation, regulariser Jacobians, SyMo, seed ensembles (× separate runs), pixels (frames/s), time to accuracy; tables in benchmarks/results/
	$(BIN)/python benchmarks/speed.py --threads 1 $(ARGS)
	$(BIN)/python benchmarks/jacobian_speed.py --threads 1
	$(BIN)/python benchmarks/symo_speed.py --threads 1
	$(BIN)/python benchmarks/ensemble_speed.py --threads 1
	$(BIN)/python benchmarks/pixel_speed.py --threads 1
	$(BIN)/python benchmarks/time_to_accuracy.py

benchmark:  ## a benchmark profile, e.g. make benchmark ARGS="profile=quick" (smoke|quick|zhong|finzi|lim_kasim|pixels|santos|xiao|control)
	$(BIN)/python -m encons.benchmark $(ARGS)

report:  ## rebuild a benchmark's tables and figures without training, e.g. make report ARGS=benchmarks/results/quick
	$(BIN)/python -m encons.report $(ARGS)

clean:
	rm -rf outputs multirun .cache/encons .pytest_cache build dist *.egg-info
	find . -name __pycache__ -type d -prune -exec rm -rf {} +
