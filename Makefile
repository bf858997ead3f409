# icenav: two commands do everything on a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: install browser test lint typecheck pytest bench soak demo docs clean

$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[dev,gym,cluster]'
	touch $(STAMP)

install: $(STAMP)

# Debian chromium + playwright for the console's browser test (apt-get; idempotent)
browser: $(STAMP)
	bash scripts/install-browser.sh $(PY)

lint: $(STAMP)
	$(VENV)/bin/ruff check src tests benchmarks examples fuzz docs/make_figures.py docs/figures
	$(VENV)/bin/ruff format --check src tests benchmarks examples fuzz docs/make_figures.py docs/figures

typecheck: $(STAMP)
	$(VENV)/bin/mypy

pytest: $(STAMP) browser
	$(PY) -m pytest

test: lint typecheck pytest

bench: $(STAMP)
	$(PY) -m benchmarks

# the full soak: the race harness at 1,000,000 cycles (make test runs 100,000), then a
# simulated 4-hour procedure at 100 Hz (about 20 minutes; make test runs a 2-minute one)
soak: $(STAMP)
	$(PY) -m benchmarks races
	$(PY) -m icenav.apps.soak --hours 4 --json soak-4h.json

demo: $(STAMP)
	$(VENV)/bin/icenav demo

docs: $(STAMP)
	$(PY) docs/make_figures.py

clean:
	rm -rf $(VENV) build dist *.egg-info .pytest_cache .mypy_cache .ruff_cache
