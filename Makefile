# The two set-up commands of the README: `make demo` (main job) and `make test`.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: demo view test lint docs evaluate bench install clean

$(STAMP): pyproject.toml constraints.txt
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -c constraints.txt -e '.[dev,onnx,openvino,baselines,plots,lerobot,ros]'
	touch $(STAMP)

install: $(STAMP)

DEMO_OUT ?= cnep-demo

# The demo writes into $(DEMO_OUT), replacing what an earlier demo wrote there.
demo: $(STAMP)
	$(BIN)/cnep demo --out $(DEMO_OUT) --force
	@echo "Open the view: make view"

# The demo's scene-change recording in the Rerun viewer (installed in .venv, so this works from any shell).
view: $(STAMP)
	$(BIN)/rerun $(DEMO_OUT)/demo.rrd

evaluate: $(STAMP)
	$(BIN)/cnep evaluate

test: $(STAMP)
	CI=1 $(BIN)/python -m pytest -q

lint: $(STAMP)
	$(BIN)/ruff format --check .
	$(BIN)/ruff check .

# The CLI reference page, generated from the parsers (tests/test_docs.py checks it is current).
docs: $(STAMP)
	$(BIN)/python -m cnep.pipeline.cli.reference docs/reference/cli.md

bench: $(STAMP)
	$(BIN)/python -m benchmarks

clean:
	rm -rf $(VENV) build *.egg-info
