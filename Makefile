# Every target works from a fresh clone on a machine that has only python3.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
DEMO_DIR ?= data/demo

.PHONY: install test lint demo bench default-model clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --upgrade pip
	# torch first, pinned to the CPU wheel that lies on this disk (see README).
	$(PY) -m pip install "torch==2.13.0"
	$(PY) -m pip install -e ".[dev]"
	touch $(STAMP)

install: $(STAMP)

lint: $(STAMP)
	$(VENV)/bin/ruff check pipeline research app annotator_ui tests bench
	$(VENV)/bin/lint-imports

test: $(STAMP)
	$(MAKE) lint
	$(VENV)/bin/pytest -q

demo: $(STAMP)
	$(VENV)/bin/tracklabel demo --out $(DEMO_DIR)

# Retrain the model shipped in pipeline/models/default.pt (simulated campus, the product's
# training defaults; about an hour on 2 busy CPU cores) and its .json summary.
default-model: $(STAMP)
	$(VENV)/bin/tracklabel experiment default-model --out pipeline/models/default.pt

bench: $(STAMP)
	$(PY) -m bench.run_all --out bench/results

clean:
	rm -rf $(VENV) build *.egg-info
