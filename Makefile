# Two commands on a fresh machine: `make demo` and `make test`. Both create .venv when missing.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
TRAIN_STAMP := $(VENV)/.installed-train
export DEPTHAI_TELEMETRY := 0
export DEPTHAI_PROTOCOL := usb
export DEPTHAI_DISABLE_STARTUP_NOTIFICATIONS := 1

.PHONY: demo test bench docs train eval-easy eval-hard report-hard venv venv-train clean

venv: $(STAMP)

$(STAMP): requirements.txt pyproject.toml setup.py
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -r requirements.txt
	$(BIN)/python -m pip install -q --no-deps -e .
	touch $(STAMP)

# PyTorch (CPU) for training and the RM-net export tests: only `make test` and `make train` need it
venv-train: $(TRAIN_STAMP)

$(TRAIN_STAMP): $(STAMP) requirements-train.txt
	$(BIN)/python -m pip install -q -r requirements-train.txt
	touch $(TRAIN_STAMP)

demo: $(STAMP)
	$(BIN)/mmatch demo --out mmatch-demo

test: $(STAMP) $(TRAIN_STAMP)
	$(BIN)/python -m pytest tests

train: $(TRAIN_STAMP)
	nice $(BIN)/mmatch train --out train-results

bench: $(STAMP)
	$(BIN)/mmatch bench --out bench-results

docs: $(STAMP)
	$(BIN)/mmatch config --docs docs

eval-easy: $(STAMP)
	$(BIN)/mmatch sim --out data/easy --n 200 --seed 0 --mode easy --jobs 2
	$(BIN)/mmatch eval data/easy --json data/easy-eval.json --jobs 2

eval-hard: $(STAMP)
	$(BIN)/mmatch sim --out data/hard --n 200 --seed 0 --mode hard --jobs 2
	$(BIN)/mmatch eval data/hard --json data/hard-eval.json --jobs 2

# the comparison of the README (Open3D peers need `pip install 'mmatch[baselines]'`, else skipped)
report-hard: $(STAMP)
	$(BIN)/mmatch sim --out data/hard-wide --n 200 --seed 0 --mode hard --physics wide --jobs 2
	$(BIN)/mmatch report data/hard-wide --out data/report-hard-wide --jobs 2 --confidence-threshold 0

clean:
	rm -rf $(VENV) mmatch-demo bench-results train-results data
