# The two set-up commands of the README: `make demo` (main job) and `make test`. Each installs what its job
# needs into .venv/ (the project's extras, pinned by constraints.txt), with pip's own progress, then runs it.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
BENCH  ?=

# What each job installs besides the core (torch, torchvision, rerun-sdk, mcap, OpenCV, safetensors):
# the demo extracts features with ONNX Runtime (its fastest fp32 backend here, and its int8 one) and draws its
# summary figure with matplotlib; the evaluation adds the baselines (movement-primitives, gmr);
# the tests and the linter everything: pytest and ruff, OpenVINO, pyarrow + PyAV (LeRobot), rosbags, MuJoCo +
# Gymnasium (the simulator); `make sim`, the closed loop in the simulator, ONNX Runtime (the exported policies),
# MuJoCo + Gymnasium and the baselines (`cnep sim pick-place` runs them).
EXTRAS_demo     := onnx,plots
EXTRAS_evaluate := onnx,baselines,plots
EXTRAS_test     := dev,onnx,openvino,baselines,plots,lerobot,ros,sim,dask
EXTRAS_sim      := onnx,sim,baselines

.PHONY: demo view sim test test-fast lint docs evaluate bench install clean

$(BIN)/python:
	@echo "== creating $(VENV) with $(PYTHON)"
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --upgrade pip

$(VENV)/.installed-%: pyproject.toml constraints.txt | $(BIN)/python
	@echo "== $*: installing cnep-pipeline[$(EXTRAS_$*)] and its dependencies into $(VENV) (torch among them)."
	@echo "   The first install fetches torch with its CUDA libraries (.venv grows to about 7 GB) and takes about"
	@echo "   3 minutes; pip's progress follows, but its last step, 'Installing collected packages', prints nothing"
	@echo "   for a minute or two while it unpacks."
	@echo "   A CPU-only machine can skip the CUDA libraries: see 'CPU only' in docs/getting-started.md."
	$(BIN)/python -m pip install -c constraints.txt -e '.[$(EXTRAS_$*)]'
	@touch $@

install: $(VENV)/.installed-test

DEMO_OUT ?= cnep-demo

# The demo writes into $(DEMO_OUT), replacing what an earlier demo wrote there.
demo: $(VENV)/.installed-demo
	$(BIN)/cnep demo --out $(DEMO_OUT) --force
	@echo "Open the view: make view"

# The demo's scene-change recording in the Rerun viewer where there is a display, else in Rerun's web viewer served
# here, with the address to open (installed in .venv, so this works from any shell).
view: $(VENV)/.installed-demo
	$(BIN)/cnep view $(DEMO_OUT)/demo.rrd

SIM_OUT ?= cnep-sim

# The closed loop in the simulator, from nothing to the table (docs/how-to/evaluate-in-closed-loop.md).
sim: $(VENV)/.installed-sim
	$(BIN)/cnep sim obstacle --out $(SIM_OUT)
	@echo "Open an episode: $(BIN)/rerun $(SIM_OUT)/episodes/CNEP-seed0-online-seed0.rrd"

evaluate: $(VENV)/.installed-evaluate
	$(BIN)/cnep evaluate

# Every test, one worker process per core (pytest-xdist), handed out one at a time, slow ones first, the tests of a
# module fixture together (tests/conftest.py), so that the workers finish together. The tests start many Python
# processes that import the project, so each module's bytecode is cached (`__pycache__/`, ignored by git) even where
# the environment turns that off (PYTHONDONTWRITEBYTECODE): compiled once, not in every process.
TEST_ENV := CI=1 PYTHONDONTWRITEBYTECODE=
test: $(VENV)/.installed-test
	$(TEST_ENV) $(BIN)/python -m pytest -q -n auto --dist loadgroup

# The inner loop: every test but those marked slow (the whole pipeline's, the end-to-end commands', any over a second),
# on the same workers, in under a minute.
test-fast: $(VENV)/.installed-test
	$(TEST_ENV) $(BIN)/python -m pytest -q -n auto --dist loadgroup -m "not slow"

lint: $(VENV)/.installed-test
	$(BIN)/ruff format --check .
	$(BIN)/ruff check .

# The reference pages generated from the code: the CLI's, the training recipe's (tests/test_docs.py checks them).
docs: $(VENV)/.installed-demo
	$(BIN)/python -m cnep.pipeline.cli.reference docs/reference/cli.md
	$(BIN)/python -m cnep.pipeline.sim.recipe docs/reference/training-recipe.md

# `make bench` lists the benchmarks; `make bench BENCH=replay` runs one, `make bench BENCH=all` every one but those
# that take hours (run by name).
bench: $(VENV)/.installed-test
	$(BIN)/python -m benchmarks $(BENCH)

clean:
	rm -rf $(VENV) build *.egg-info
