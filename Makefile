# The README's two commands: `make demo` and `make test`. Both set up first (idempotent).
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.simreel-setup
TEST_STAMP := $(VENV)/.simreel-test-extras
MESA   := $(VENV)/share/simreel/mesa
DEMO   := demo_out
PYTEST_ARGS ?=
# One worker per core, each test file on one worker (module fixtures are built once; the code blocks of README.md
# and docs/ run in order, page by page).
PARALLEL := -n auto --dist loadfile

.PHONY: setup test-setup demo test test-all test-gpu lint bench docs clean lerobot-env

# setuptools' "Editable installation" banner (a warning about folders named like the package) says nothing to a user
# of `make`: kept out of the output.
QUIET_PIP := PYTHONWARNINGS="ignore:Editable installation"

NODE_TOOL := tools/mcap_ts

# What `make demo` needs: simreel and its dependencies (torch as a CPU build where there is no GPU), and software
# Vulkan. `make test` adds the test and Ray extras (test-setup).
setup: $(STAMP)

test-setup: $(TEST_STAMP) $(NODE_TOOL)/node_modules/.package-lock.json

# The TypeScript MCAP reader Foxglove uses, for the tests that read simreel's files with it (skipped without npm).
$(NODE_TOOL)/node_modules/.package-lock.json: $(NODE_TOOL)/package-lock.json
	@if command -v npm >/dev/null 2>&1; then \
	   (cd $(NODE_TOOL) && npm ci --no-audit --no-fund --loglevel=error) || echo "warning: npm ci failed in $(NODE_TOOL)"; \
	 else echo "warning: no npm: the tests with the TypeScript MCAP reader will be skipped"; fi

$(STAMP): pyproject.toml tools/install_torch.sh tools/fetch_lavapipe.sh
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip setuptools wheel
	tools/install_torch.sh $(BIN)/pip
	$(QUIET_PIP) $(BIN)/pip install -q -e .
	@# Software Vulkan for SAPIEN where no GPU renders; without it simreel still runs state-only.
	@if command -v nvidia-smi >/dev/null 2>&1; then echo "NVIDIA GPU: no software Vulkan needed"; \
	 else tools/fetch_lavapipe.sh $(MESA) || echo "warning: no software Vulkan fetched; simreel will run state-only"; fi
	@touch $(STAMP)

# pytest, ruff, the docs site's tools, Foxglove's schemas and Ray (the tests run `replay --ray`).
$(TEST_STAMP): $(STAMP)
	$(QUIET_PIP) $(BIN)/pip install -q -e '.[test,ray]'
	@# Headless Chromium (Debian's), for the tests that open the web viewer in a browser (skipped without it).
	@if [ -x /usr/bin/chromium ]; then :; \
	 elif command -v apt-get >/dev/null 2>&1 && [ "$$(id -u)" = 0 ]; then \
	   (apt-get install -y -q chromium chromium-driver >/dev/null 2>&1 || \
	    (apt-get update -q >/dev/null && apt-get install -y -q chromium chromium-driver >/dev/null)) || \
	   echo "warning: apt-get could not install chromium: the browser tests will be skipped"; \
	 else echo "warning: no /usr/bin/chromium (apt-get install chromium as root): the browser tests will be skipped"; fi
	@touch $(TEST_STAMP)

# Record a few PickCube-v1 episodes, show what the file holds, replay and verify every step (writing
# the replay and a JSON report), and build a Rerun session of episode 0 beside its replay. Everything goes
# to $(DEMO)/; the last lines, printed by `simreel view`, say how to open the session (where there is no display:
# how to serve it to a browser).
demo: setup
	@mkdir -p $(DEMO)
	$(BIN)/simreel record PickCube-v1 -o $(DEMO)/pickcube.h5 -n 3 --seed 0 --overwrite
	$(BIN)/simreel inspect $(DEMO)/pickcube.h5
	$(BIN)/simreel replay $(DEMO)/pickcube.h5 -o $(DEMO)/pickcube.replayed.h5 --overwrite --report $(DEMO)/report.json
	$(BIN)/simreel view $(DEMO)/pickcube.h5 --episode 0 --compare $(DEMO)/pickcube.replayed.h5 --save $(DEMO)/pickcube.rrd --overwrite

lint: test-setup
	$(BIN)/ruff check simreel recorders replay training viewers tests benchmarks

test: lint
	$(BIN)/python -m pytest $(PARALLEL) --durations=25 $(PYTEST_ARGS)

test-all: lint
	$(BIN)/python -m pytest $(PARALLEL) -m "not gpu" $(PYTEST_ARGS)

test-gpu: test-setup
	$(BIN)/python -m pytest -m gpu $(PYTEST_ARGS)

bench: test-setup
	$(BIN)/python benchmarks/record_overhead.py
	$(BIN)/python benchmarks/record_overhead.py --format mcap
	$(BIN)/python benchmarks/bench_formats.py
	$(BIN)/python benchmarks/bench_replay.py
	$(BIN)/python benchmarks/bench_view.py
	$(BIN)/python benchmarks/bench_convert.py
	$(BIN)/python benchmarks/bench_convert.py --what rgb
	$(BIN)/python benchmarks/bench_training.py

# LeRobot's own dataset loader (lerobot 0.4.4) in a venv of its own, for the tests that read `simreel export --to
# lerobot` with it (they are skipped without it): lerobot pins a torch and a rerun-sdk simreel's venv cannot hold.
LEROBOT_VENV := .cache/lerobot-venv
lerobot-env: $(LEROBOT_VENV)/.simreel-lerobot

$(LEROBOT_VENV)/.simreel-lerobot: tools/lerobot_env.sh tools/install_torch.sh
	tools/lerobot_env.sh $(LEROBOT_VENV)

# The documentation site, strictly (a broken link, a missing anchor or a page left out of the nav fails it), into
# site/. mkdocs comes with the test extra; the docs extra installs it where setup ran before it did.
docs: setup
	@$(BIN)/python -c "import mkdocs, material" 2>/dev/null || $(QUIET_PIP) $(BIN)/pip install -q -e '.[docs]'
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict

clean:
	rm -rf $(DEMO) site .pytest_cache .ruff_cache
