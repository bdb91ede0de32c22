# Every target works from a fresh clone on a machine that has only python3.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
# The runtime (install, demo) and, on top, the test, bench and lint tools (test, lint, bench).
STAMP := $(VENV)/.installed
DEV_STAMP := $(VENV)/.installed-dev
# Every package pinned to the version tested here (pip-compatible; `make lock` rewrites it).
PIP_INSTALL := $(PY) -m pip install -c constraints.txt
DEMO_DIR ?= data/demo
PORT ?= 8000
VIEWER_PORT ?= 8080

.PHONY: install test lint demo bench default-model screenshots lock clean

$(STAMP): pyproject.toml constraints.txt
	$(PYTHON) -m venv $(VENV)
	$(PIP_INSTALL) pip
	# torch first: the 2.13.0 CPU wheel that lies on this disk (README: CPU or CUDA wheels).
	$(PIP_INSTALL) "torch==2.13.0"
	$(PIP_INSTALL) -e .
	touch $(STAMP)

$(DEV_STAMP): $(STAMP)
	$(PIP_INSTALL) -e ".[dev]"
	touch $(DEV_STAMP)

install: $(STAMP)

lint: $(DEV_STAMP)
	$(VENV)/bin/ruff check pipeline research app annotator_ui tests bench
	$(VENV)/bin/lint-imports

test: $(DEV_STAMP)
	$(MAKE) lint
	$(VENV)/bin/pytest -q -n 2

demo: $(STAMP)
	$(VENV)/bin/tracklabel demo --out $(DEMO_DIR) --port $(PORT) --viewer-port $(VIEWER_PORT)

# The README's two screenshots, taken by the browser tests of the repair panel (needs chromium).
screenshots: $(DEV_STAMP)
	TRACKLABEL_SCREENSHOT_DIR=docs $(VENV)/bin/pytest -q tests/annotator_ui/test_browser_repair.py \
		-k "split_two_objects or aggregated_view"

# Retrain the model shipped in pipeline/models/default.pt (simulated campus, the product's
# training defaults; about an hour on 2 busy CPU cores) and its .json summary.
default-model: $(STAMP)
	$(VENV)/bin/tracklabel experiment default-model --out pipeline/models/default.pt

bench: $(DEV_STAMP)
	$(PY) -m bench.run_all --out bench/results

# Resolve every dependency afresh in a scratch venv and pin what pip chose into constraints.txt.
lock:
	rm -rf build/lock-venv && $(PYTHON) -m venv build/lock-venv
	build/lock-venv/bin/python -m pip install -q --upgrade pip
	build/lock-venv/bin/python -m pip install -q "torch==2.13.0"
	build/lock-venv/bin/python -m pip install -q -e ".[dev]"
	( echo "# pip constraints: every package make install / make test installs, at the version tested."; \
	  echo "# Regenerate with 'make lock'. torch is the public version: the CPU and CUDA wheels both match."; \
	  build/lock-venv/bin/python -m pip freeze --all --exclude-editable | sed -e 's/^torch==\([^+]*\)+.*/torch==\1/' ) \
	  > constraints.txt
	rm -rf build/lock-venv

clean:
	rm -rf $(VENV) build *.egg-info
