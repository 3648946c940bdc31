# make demo: create .venv, install, run the default scenario end to end.
# make test: same install plus the browser and PDF tools of the report tests, then ruff and every test (on both cores).
# make check: ruff, mypy and the quick tier (every test not marked slow: at most about two minutes on two cores), for
# everyday work.
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
PYTHON ?= python3
PYTEST := $(BIN)/pytest -q -n 2 --dist worksteal
# worksteal: each worker runs a contiguous half of the tests (a module's fixtures built once) and takes
# half of the other's remaining tests when it runs out, so neither core idles behind one long file.

.PHONY: install system-deps demo test check lint typecheck bench mutate clean

# The install by uv (its resolver and parallel unpacking: about 10 s where pip takes about 70 s), pip where uv
# cannot be had or cannot install (the same requirements, the same versions).
$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	{ $(BIN)/python -m pip install --quiet "uv>=0.4" && $(BIN)/uv pip install --quiet --python $(BIN)/python -e ".[test]"; } \
	  || { $(BIN)/python -m pip install --quiet --upgrade pip && $(BIN)/python -m pip install --quiet -e ".[test]"; }
	touch $(STAMP)

install: $(STAMP)

# Headless Chromium and poppler-utils (pdftoppm) for the report tests (Debian packages).
system-deps:
	@command -v chromium >/dev/null && command -v pdftoppm >/dev/null || { \
	  SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
	  $$SUDO apt-get update -qq && $$SUDO apt-get install -y -qq chromium poppler-utils >/dev/null; }

demo: install
	$(BIN)/dvfc simulate examples/ur5_circle.toml --out out/demo
	$(BIN)/dvfc certify examples/ur5_circle.toml --out out/demo
	$(BIN)/dvfc verify examples/ur5_circle.toml --out out/demo
	$(BIN)/dvfc report examples/ur5_circle.toml --out out/demo
	@echo "demo outputs in out/demo: report.html, report.pdf, trajectory.npz, summary.json, certificate.json, verification.json"

lint: install
	$(BIN)/ruff check .

# make typecheck: mypy on dvfc.models, dvfc.analysis and dvfc.reports ([tool.mypy] in pyproject.toml). mypy does not
# follow the editable install's import hook, so it reads the package through links laid out as installed.
TYPECHECK := $(VENV)/typecheck/dvfc
typecheck: install
	mkdir -p $(TYPECHECK)
	ln -sfn ../../../dvfc/__init__.py $(TYPECHECK)/__init__.py
	for layer in models analysis reports; do ln -sfn ../../../$$layer $(TYPECHECK)/$$layer; done
	$(BIN)/mypy

# The notebooks first: each is one long test (up to about 1.5 min), started while the other core runs the tests
# it can share out, not left for the end where one core would wait on it.
test: lint typecheck system-deps
	$(PYTEST) --durations=25 --nbmake notebooks tests

check: lint typecheck
	$(PYTEST) -m "not slow" tests

# make mutate: break the code on purpose (tests/mutation/harness.py) and check every mutation is caught (245 mutations; 235: 1854 s on two cores after a 701 s baseline when last measured, so about 43 min; results in tests/mutation/MUTATIONS.md).
mutate: install
	$(BIN)/python tests/mutation/harness.py --write

# make bench: every benchmark; their numbers written to docs/measured.md.
bench: install
	$(BIN)/python benchmarks/measured.py

clean:
	rm -rf out .pytest_cache .ruff_cache
