# One command each: `make demo`, `make test`, `make bench`. Each creates .venv if missing.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: demo test bench clean

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

test: $(STAMP)
	$(BIN)/python -m pytest -q

bench: $(STAMP)
	$(BIN)/python -m pip install --quiet -e '.[test,bench]'
	$(BIN)/python benchmarks/run.py

clean:
	rm -rf $(VENV) out build src/*.egg-info
