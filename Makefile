# jaxlc — one command each: `make demo`, `make test` (both build what they need).
PYTHON ?= python3.11
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
DEMO   := build/demo

.PHONY: setup demo test bench paper lint format meshes clean

BLENDER_VENV  := .venv-blender
BLENDER_STAMP := $(BLENDER_VENV)/.installed

## setup: create .venv (jaxlc, test tools, Dask) and .venv-blender (bpy 5.0, numpy<2); idempotent
setup: $(STAMP) $(BLENDER_STAMP)

$(STAMP): pyproject.toml requirements/constraints.txt
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --disable-pip-version-check \
		-c requirements/constraints.txt -e '.[test,dask]'
	@touch $@

# bpy cannot share .venv: it pins numpy<2, jax needs numpy>=2 (ARCHITECTURE.md).
$(BLENDER_STAMP): requirements/blender.txt
	@test -x $(BLENDER_VENV)/bin/python || $(PYTHON) -m venv $(BLENDER_VENV)
	$(BLENDER_VENV)/bin/python -m pip install --quiet --disable-pip-version-check \
		-r requirements/blender.txt
	@touch $@

## demo: a Falcon 9 second stage spinning end over end over a real 20-minute pass seen from Mt Stromlo
demo: setup
	$(BIN)/jaxlc passes --tle data/tle/falcon9_rb.tle --norad 45921 --site mt-stromlo \
		--start 2020-08-10T00:00:00Z --days 1
	$(BIN)/jaxlc geometry pass --tle data/tle/falcon9_rb.tle --norad 45921 --site mt-stromlo \
		--start 2020-08-10T18:00:00Z --duration-s 1200 --step-s 1 --exposure-s 1 \
		-o $(DEMO)/geometry.csv
	$(BIN)/jaxlc render s4_falcon9 $(DEMO)/geometry.csv \
		-o $(DEMO)/lightcurve.csv --plot $(DEMO)/lightcurve.png
	$(BIN)/jaxlc period $(DEMO)/lightcurve.csv --plot $(DEMO)/period_s4.png
	$(BIN)/jaxlc period tests/data/mmt/10025_10114859.txt --plot $(DEMO)/period.png
	@echo "demo output: $(DEMO)/geometry.csv, $(DEMO)/lightcurve.csv, $(DEMO)/lightcurve.png, $(DEMO)/period_s4.png, $(DEMO)/period.png"

## test: the whole suite
test: setup
	$(BIN)/python -m pytest -q

## bench: speed and accuracy tables (CSV under experiments/results/)
bench: setup
	$(BIN)/python experiments/bench_render.py
	$(BIN)/python experiments/bench_geometry.py
	$(BIN)/python experiments/pareto.py

## paper: the seed paper's figures and tables (experiments/paper/, ~5 min on 2 cores)
paper: setup
	$(BIN)/python experiments/paper/falcon9_vs_cylinder.py
	$(BIN)/python experiments/paper/motion_blur.py
	$(BIN)/python experiments/paper/blender_calibration.py
	$(BIN)/python experiments/paper/cost.py
	@echo "paper figures and tables: experiments/results/paper/ (see experiments/README.md)"

## lint: ruff
lint: setup
	$(BIN)/ruff check jaxlc calibrate tests experiments
	$(BIN)/ruff format --check jaxlc calibrate tests experiments

format: setup
	$(BIN)/ruff format jaxlc calibrate tests experiments

## meshes: rebuild the shipped shape models
meshes: setup
	$(BIN)/python experiments/make_meshes.py

clean:
	rm -rf build .pytest_cache .ruff_cache .hypothesis
