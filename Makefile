# jaxlc — one command each: `make demo`, `make test` (both build what they need).
PYTHON ?= python3.11
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
DEMO   := build/demo

.PHONY: setup demo test bench lint format meshes clean

## setup: create .venv with jaxlc, its test tools and the Dask extra (idempotent)
setup: $(STAMP)

$(STAMP): pyproject.toml requirements/constraints.txt
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --disable-pip-version-check \
		-c requirements/constraints.txt -e '.[test,dask]'
	@touch $@

## demo: a spinning Falcon 9 second stage over a synthetic 20-minute pass (CSV + PNG)
demo: setup
	$(BIN)/jaxlc geometry synthetic -o $(DEMO)/geometry.csv --duration-s 1200 --step-s 1 \
		--phase-start-deg 25 --phase-end-deg 110 --range-km 1200 --range-end-km 2600
	$(BIN)/jaxlc render experiments/scenes/s4_falcon9.toml $(DEMO)/geometry.csv \
		-o $(DEMO)/lightcurve.csv --plot $(DEMO)/lightcurve.png
	@echo "demo output: $(DEMO)/lightcurve.csv, $(DEMO)/lightcurve.png"

## test: the whole suite
test: setup
	$(BIN)/python -m pytest -q

## bench: speed and accuracy tables (CSV under experiments/results/)
bench: setup
	$(BIN)/python experiments/bench_render.py

## lint: ruff
lint: setup
	$(BIN)/ruff check jaxlc calibrate tests experiments meshes
	$(BIN)/ruff format --check jaxlc calibrate tests experiments meshes

format: setup
	$(BIN)/ruff format jaxlc calibrate tests experiments meshes

## meshes: rebuild the shipped shape models
meshes: setup
	$(BIN)/python meshes/make_meshes.py

clean:
	rm -rf build .pytest_cache .ruff_cache .hypothesis
