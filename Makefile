# nerfkit: the two commands of the README.
#   make demo   set up .venv and run the main job on the bundled lego scene
#   make test   set up .venv and run the test suite's fast lane (the tests not marked slow)
#   make test-all   the whole suite, slow end-to-end tests included (what CI runs)
#   make lint   ruff (lint and format check) over the sources, tests, benchmarks and docs scripts; mypy over the sources
# TORCH_SPEC picks the PyTorch build; the default is the CPU wheel these machines carry.
# On a CUDA machine: make demo TORCH_SPEC="torch>=2.4"

PYTHON ?= python3
VENV ?= .venv
TORCH_SPEC ?= torch==2.13.0
BIN = $(VENV)/bin

.PHONY: setup demo test lint clean

setup: $(VENV)/.installed

$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet "$(TORCH_SPEC)"
	$(BIN)/python -m pip install --quiet -e ".[test]"
	touch $@

demo: setup
	$(BIN)/nerfkit demo

# -n auto: one pytest-xdist worker per core (tests/conftest.py gives each one torch thread)
test: setup
	$(BIN)/python -m pytest -m "not slow" -n auto

test-slow: setup
	$(BIN)/python -m pytest -m slow -n auto

test-all: setup
	$(BIN)/python -m pytest -n auto

lint: setup
	$(BIN)/ruff check src tests benchmarks docs
	$(BIN)/ruff format --check src tests benchmarks docs
	$(BIN)/mypy src/nerfkit

clean:
	rm -rf $(VENV) runs
