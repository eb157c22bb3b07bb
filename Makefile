# tactex: `make demo` and `make test` each build .venv on a fresh machine, then run.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed-stamp
OUT ?= runs/demo

.PHONY: demo test bench lint clean-venv

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[dev,fast]'
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/tactex demo --out $(OUT)

test: $(STAMP)
	$(VENV)/bin/ruff check tactex tests bench examples
	$(PY) -m pytest -q

bench: $(STAMP)
	$(PY) bench/run.py --out bench/results.json

lint: $(STAMP)
	$(VENV)/bin/ruff check tactex tests bench examples

clean-venv:
	rm -rf $(VENV)
