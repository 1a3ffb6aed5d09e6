# One command each: `make demo`, `make test`, `make bench`. Each creates .venv if missing.
SHELL  := /bin/bash
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: demo test bench clean chromium

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(STAMP)

demo: $(STAMP)
	@echo "== 1. The paper's experiment (simulated tracks of 24 corners, 4 views) =="
	$(BIN)/transcalib calibrate --tracks examples/paper/tracks.csv --poses examples/paper/poses.csv \
		--unit mm --robot-sigma 0.1 --out out/demo-paper --truth examples/paper/truth.json
	@echo
	@echo "== 2. From images: 5 rendered views at known translations, tracked, calibrated =="
	$(BIN)/transcalib calibrate --images examples/images/view*.png --poses examples/images/poses.csv \
		--unit mm --out out/demo-images --truth examples/images/truth.json
	@echo
	@echo "== 3. Two sessions (2-axis moves at two wrist orientations): full K, R_X and 2 of 3 components of t_X =="
	$(BIN)/transcalib calibrate --images examples/sessions2/view*.png --poses examples/sessions2/poses.csv \
		--unit mm --out out/demo-sessions2 --truth examples/sessions2/truth.json
	@echo
	@echo "== 4. Three sessions: K and the full camera-to-flange transform, no target =="
	$(BIN)/transcalib calibrate --images examples/sessions3/view*.png --poses examples/sessions3/poses.csv \
		--unit mm --out out/demo-sessions3 --truth examples/sessions3/truth.json

test: $(STAMP) chromium
	$(BIN)/python -m pytest -q

# the report's browser test needs a real browser: Debian's chromium (idempotent)
chromium:
	@command -v chromium >/dev/null || (apt-get update -qq && apt-get install -y -qq chromium >/dev/null)

bench: $(STAMP)
	$(BIN)/python -m pip install --quiet -e '.[test,bench]'
	mkdir -p out
	set -o pipefail; $(BIN)/python benchmarks/run.py 2>&1 | tee out/bench.log
	$(BIN)/python benchmarks/make_results_doc.py out/bench.log

clean:
	rm -rf $(VENV) out build src/*.egg-info
