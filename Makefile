# Quick start: `make run` trains the Taxi hybrid agent, `make test` runs the tests.
# Both create the virtualenv .venv on first use (torch 2.13.0 CPU wheel first, then the package).
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
ARGS ?=
# pytest-xdist processes for `make test` (one torch thread each)
TEST_WORKERS ?= 2

.PHONY: run test lint docs test-cuda install clean

$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q torch==2.13.0
	$(PY) -m pip install -q -e ".[test,lint,docs,tensorboard]"
	touch $@

install: $(VENV)/.installed

# the paper's agent on Taxi with its built-in optimal expert; extra Hydra overrides via ARGS="variant=a2c seed=3"
run: $(VENV)/.installed
	$(PY) recipes/taxi.py $(ARGS)

test: $(VENV)/.installed
	$(PY) -m pytest -q -n $(TEST_WORKERS) tests

# ruff (lint + format check) and mypy, as configured in pyproject.toml; `pre-commit install` runs them on commit
lint: $(VENV)/.installed
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .
	$(VENV)/bin/mypy

# the whole suite with every run on the GPU (a machine with CUDA; the CI machine has none)
test-cuda: $(VENV)/.installed
	TORCHRL_HYBRID_TEST_DEVICE=cuda $(PY) -m pytest -q tests

clean:
	rm -rf $(VENV) outputs site .pytest_cache .hypothesis

# the documentation site (mkdocs-material, API reference from the docstrings, the notebooks) into site/;
# warnings are errors, as in CI. `.venv/bin/mkdocs serve` serves it while you edit.
docs: $(VENV)/.installed
	NO_MKDOCS_2_WARNING=1 $(VENV)/bin/mkdocs build --strict --quiet
