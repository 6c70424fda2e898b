# advsim_ros: two commands do everything on a fresh machine.
#   make demo   full run of the main job on the embedded default data (installs what it needs)
#   make test   every test and static check (installs what it needs)
SHELL := /bin/bash
VENV := .venv
PY := $(VENV)/bin/python
DEMO_OUT ?= out/demo

.PHONY: setup test lint typecheck pytest demo bench clean

setup:
	@bash scripts/setup.sh

lint: setup
	$(PY) -m ruff check conftest.py src tests bench scripts
	$(PY) -m ruff format --check conftest.py src tests bench scripts
	$(VENV)/bin/hadolint docker/Dockerfile

typecheck: setup
	$(PY) -m mypy

pytest: setup
	$(PY) -m pytest

test: lint typecheck pytest

demo: setup
	$(VENV)/bin/advsim demo -o $(DEMO_OUT)

bench: setup
	@for b in bench/bench_*.py; do echo "== $$b"; $(PY) $$b || exit 1; done

clean:
	rm -rf build out .pytest_cache .mypy_cache .ruff_cache
