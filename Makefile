# Two commands on a fresh machine: `make run` (the main job on the embedded default scenario)
# and `make test` (the test suite but its runs marked slow; `make test-slow` runs those). All
# depend on `make setup`, which (re)installs the project into .venv/ only when pyproject.toml
# changed.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: setup run test test-slow bench docs clean

setup: $(STAMP)

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	# torch first, pinned: the CPU wheel on local disk (a looser pin pulls a multi-GB CUDA build)
	$(BIN)/pip install --quiet torch==2.13.0
	$(BIN)/pip install --quiet -e '.[dev,vision,viz,reid,docs]'
	touch $(STAMP)

# The main job: one edge_node process per camera of the embedded default scenario (terrace-sim,
# 4 cameras in a chain) talking over Zenoh on loopback; prints the per-node metrics table, saves
# the run's Rerun recording (runs/latest.rrd) and prints the command that opens it.
run: setup
	$(BIN)/sim_cluster up --scenario terrace-sim --topology chain --config dkf+lda+dtm --seed 0 --out runs/latest --rerun save runs/latest.rrd

# The suite without the long multi-process and multi-seed runs (marked slow): under 10 minutes
# on a 2-core machine, and it passes on a busy one. `make test-slow` runs the slow ones alone.
test: setup
	$(BIN)/python -m pytest -q -m "not slow"

test-slow: setup
	$(BIN)/python -m pytest -q -m slow

bench: setup
	$(BIN)/sim_cluster bench

# The documentation site (mkdocs-material + mkdocstrings) into site/; --strict: a broken link or
# reference fails. The tables are rendered from docs/results/ first (sim_cluster report).
docs: setup
	$(BIN)/sim_cluster report
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict --site-dir site

clean:
	rm -rf $(VENV) runs site .pytest_cache
