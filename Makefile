# The user's verbs; README.md says what each one does and writes.
SHELL := /bin/bash
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

# Dataset: no arguments = the procedural demo corpus into data/demo.
SOURCE ?= synth
INPUT ?=
OUT ?= data/demo
CLIPS ?= 2000
SEED ?= 0
WORKERS ?= 2
ARGS ?=
DEMO_SOURCE ?= data/demo_src

# Training, sampling, evaluation.
PRESET ?= demo
DATASET ?= data/demo
CHECKPOINTS ?= checkpoints/$(PRESET)
TEXT ?= a person walks forward and then waves with the right hand

.PHONY: install test lint dataset contact-sheet train-ae train-len train-t2m train-eval train \
	sample eval demo bench

install: $(STAMP)

$(STAMP): setup.cfg pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[test]'
	touch $(STAMP)

test: install
	$(PY) -m pytest -q tests

lint: install
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .

dataset: install
ifeq ($(SOURCE),synth)
	test -f $(DEMO_SOURCE)/source.json || $(PY) -m dataset_tools synth --out $(DEMO_SOURCE) --clips $(CLIPS) --seed $(SEED) --workers $(WORKERS)
	$(PY) -m dataset_tools build --source joints --input $(DEMO_SOURCE) --out $(OUT) --seed $(SEED) --workers $(WORKERS) $(ARGS)
else
	@test -n "$(INPUT)" || { echo "make dataset SOURCE=$(SOURCE) needs INPUT=DIR (the source files)"; exit 2; }
	$(PY) -m dataset_tools build --source $(SOURCE) --input $(INPUT) --out $(OUT) --workers $(WORKERS) $(ARGS)
endif

contact-sheet: install
	$(PY) -m dataset_tools contact-sheet --input $(DEMO_SOURCE) --out $(DEMO_SOURCE)/contact_sheet.png --clips 12 --seed $(SEED)

train-ae: install
	$(PY) -m t2m.train autoencoder --preset $(PRESET) --dataset $(DATASET) --checkpoints $(CHECKPOINTS) $(ARGS)

train-len: install
	$(PY) -m t2m.train length --preset $(PRESET) --dataset $(DATASET) --checkpoints $(CHECKPOINTS) $(ARGS)

train-t2m: install
	$(PY) -m t2m.train generator --preset $(PRESET) --dataset $(DATASET) --checkpoints $(CHECKPOINTS) $(ARGS)

train-eval: install
	$(PY) -m t2m.train evaluator --preset $(PRESET) --dataset $(DATASET) --checkpoints $(CHECKPOINTS) $(ARGS)

train: train-ae train-len train-t2m train-eval

sample: install
	$(PY) -m t2m.sample --checkpoints $(CHECKPOINTS) --text "$(TEXT)" $(ARGS)

eval: install
	$(PY) -m t2m.evaluate --dataset $(DATASET) --checkpoints $(CHECKPOINTS) $(ARGS)

demo: install
	$(PY) -m t2m.demo $(ARGS)

bench: install
	$(PY) -m t2m.bench $(ARGS)
