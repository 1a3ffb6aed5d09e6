# One command each: `make demo`, `make test`, `make bench`. Each creates the venv if missing.
#
# `make test` installs the tested set of packages (constraints.txt, every version pinned);
# `make test-latest` runs the suite on the newest release of every dependency (.venv-latest),
# `make test-oldest` on the oldest releases pyproject.toml declares (.venv-oldest);
# `make lock` rewrites constraints.txt from the newest releases once they pass.
SHELL       := /bin/bash
PYTHON      ?= python3
VENV        ?= .venv
CONSTRAINTS ?= constraints.txt
BIN         := $(VENV)/bin
STAMP       := $(VENV)/.installed
# with a constraints file: exactly its versions; without: the newest releases
PIP_PINS    := $(if $(CONSTRAINTS),-c $(CONSTRAINTS),--upgrade --upgrade-strategy eager)

.PHONY: demo test test-latest test-oldest lock bench clean chromium

$(STAMP): pyproject.toml $(CONSTRAINTS)
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet $(PIP_PINS) -e '.[test]'
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
	@echo
	@echo "== 5. Eye-to-hand: a fixed camera watching an object the robot carries (one session + 6 single views) =="
	$(BIN)/transcalib calibrate --images examples/eye_to_hand/view*.jpg --poses examples/eye_to_hand/poses.csv \
		--setup eye-to-hand --unit mm --out out/demo-eye-to-hand --truth examples/eye_to_hand/truth.json

test: $(STAMP) chromium
	$(BIN)/python -m pip freeze --exclude-editable | grep -iE '^(numpy|scipy|opencv-python-headless)=='
	$(BIN)/python -m pytest -q -n auto

test-latest:
	rm -f .venv-latest/.installed
	$(MAKE) test VENV=.venv-latest CONSTRAINTS=

test-oldest:
	$(MAKE) test VENV=.venv-oldest CONSTRAINTS=constraints-oldest.txt

# the newest releases pass the suite: make them the tested set
lock: test-latest
	{ echo "# The tested set: every package 'make test' and 'make demo' install, pinned (pip -c)."; \
	  echo "# Regenerate with 'make lock' (newest releases, then the suite must pass on them)."; \
	  .venv-latest/bin/python -m pip freeze --exclude-editable; } > constraints.txt

# The report's browser test needs a real browser: Debian's chromium, installed with
# apt-get (root) when missing. Without it the browser tests are skipped (CI=1: they fail).
chromium:
	@command -v chromium >/dev/null || command -v chromium-browser >/dev/null || \
	if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
		echo "make test: installing Debian's chromium (apt-get) for the report's browser test"; \
		apt-get update -qq && apt-get install -y -qq chromium >/dev/null; \
	else \
		echo "make test: no chromium, and apt-get as root is not available to install it: the report's browser tests are skipped"; \
	fi

bench: $(STAMP)
	$(BIN)/python -m pip install --quiet $(PIP_PINS) -e '.[test,bench]'
	mkdir -p out
	set -o pipefail; $(BIN)/python benchmarks/run.py 2>&1 | tee out/bench.log
	$(BIN)/python benchmarks/make_results_doc.py out/bench.log

clean:
	rm -rf .venv .venv-latest .venv-oldest out build src/*.egg-info
