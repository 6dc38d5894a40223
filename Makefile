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

## demo: a tumbling Falcon 9 second stage over a real 20-minute pass seen from Mt Stromlo
demo: setup
	$(BIN)/jaxlc passes --tle data/tle/falcon9_rb.tle --norad 45921 --site mt-stromlo \
		--start 2020-08-10T00:00:00Z --days 1
	$(BIN)/jaxlc geometry pass --tle data/tle/falcon9_rb.tle --norad 45921 --site mt-stromlo \
		--start 2020-08-10T18:00:00Z --duration-s 1200 --step-s 1 --exposure-s 1 \
		-o $(DEMO)/geometry.csv
	$(BIN)/jaxlc render experiments/scenes/s4_falcon9.toml $(DEMO)/geometry.csv \
		-o $(DEMO)/lightcurve.csv --plot $(DEMO)/lightcurve.png
	@echo "demo output: $(DEMO)/geometry.csv, $(DEMO)/lightcurve.csv, $(DEMO)/lightcurve.png"

## test: the whole suite
test: setup
	$(BIN)/python -m pytest -q

## bench: speed and accuracy tables (CSV under experiments/results/)
bench: setup
	$(BIN)/python experiments/bench_render.py
	$(BIN)/python experiments/bench_geometry.py
	$(BIN)/python experiments/pareto.py

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
