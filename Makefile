# Two commands set everything up on a fresh machine:
#   make demo   installs cvsflow in .venv and runs the pipeline on the rendered demo session
#   make test   installs cvsflow with its test tools in .venv and runs the test suite
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
CORES ?= 2

.PHONY: install demo report test test-all docs slurm-up test-slurm clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

install: $(BIN)/python
	$(BIN)/python -m pip install --quiet -e ".[test]"

demo: install
	$(BIN)/snakemake --cores $(CORES)

report: demo
	$(BIN)/snakemake --cores $(CORES) --report report.html

test: install
	$(BIN)/python -m pytest -n $(CORES) --dist loadfile -m "not slow"

test-all: install
	$(BIN)/python -m pytest -n $(CORES) --dist loadfile

docs: install
	$(BIN)/python -m pip install --quiet -e ".[docs]"
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict

slurm-up:
	cluster/slurm-localhost.sh start

test-slurm: install slurm-up
	$(BIN)/python -m pip install --quiet -e ".[test,slurm]"
	CVSFLOW_SLURM=1 $(BIN)/python -m pytest tests/workflow/test_slurm.py

clean:
	rm -rf results logs benchmarks .snakemake report.html site
