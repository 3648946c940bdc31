# make demo: create .venv, install, run the default scenario end to end.
# make test: same install, then ruff and every test.
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
PYTHON ?= python3

.PHONY: install demo test lint bench clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e ".[test]"
	touch $(STAMP)

install: $(STAMP)

demo: install
	$(BIN)/dvfc simulate examples/ur5_circle.toml --out out/demo
	$(BIN)/dvfc certify examples/ur5_circle.toml --out out/demo
	$(BIN)/dvfc verify examples/ur5_circle.toml --out out/demo
	@echo "demo outputs in out/demo: trajectory.npz, summary.json, certificate.json, verification.json"

lint: install
	$(BIN)/ruff check .

test: lint
	$(BIN)/pytest -q

bench: install
	$(BIN)/python benchmarks/simulate.py
	$(BIN)/python benchmarks/certify.py

clean:
	rm -rf out .pytest_cache .ruff_cache
