# calib: two commands on a fresh clone -> `make calibrate` and `make test`.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
CALIB  := $(VENV)/bin/calib
PAPER  := sample_runs/paper
DATA   := sample_data/paper

.PHONY: setup test test-all calibrate paper docs clean

setup: $(VENV)/.installed

# torch is pinned (==2.13.0, CPU wheel) in pyproject.toml: an unpinned torch pulls a multi-GB CUDA build
$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(VENV)/bin/pip install -q --upgrade pip
	$(VENV)/bin/pip install -q -e '.[test]'
	touch $@

test: setup
	$(PY) -m pytest -q -m "not slow"

test-all: setup
	$(PY) -m pytest -q

calibrate: paper

# The paper's statistics from its own published responses (Tables 3, 5, 7 -> Tables 4, 6, 8 and Eq. 7)
paper: setup
	$(CALIB) init --run $(PAPER) --settings stages/paper.toml
	$(CALIB) pb design --run $(PAPER)
	$(CALIB) pb analyze --run $(PAPER) --responses $(DATA)/table3_pb.csv
	$(CALIB) ascent design --run $(PAPER)
	$(CALIB) ascent analyze --run $(PAPER) --responses $(DATA)/table5_ascent.csv
	$(CALIB) bbd design --run $(PAPER)
	$(CALIB) bbd analyze --run $(PAPER) --responses $(DATA)/table7_bbd.csv

docs: setup
	$(VENV)/bin/typer calib_cli.cli utils docs --name calib --output docs/cli.md

clean:
	rm -rf $(VENV) .pytest_cache .hypothesis
