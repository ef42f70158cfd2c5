# The user's verbs; README.md and docs/ say what each one does and writes.
#
# The values a user gives (TEXT, the paths, ARGS ...) reach the commands as data, never as code:
# - make does not expand them: a value given on the command line or in the environment is used
#   as written ($(call given,NAME)), so $(shell ...) in it is text;
# - the shell does not interpret them: each is passed as one single-quoted word
#   ($(call arg,NAME)), so quotes, backticks, $(...), ; | & and globs in it are text.
# ARGS holds extra options: make splits it into words at blanks and quotes each word; quotes
# inside ARGS are not interpreted (an option value with blanks needs the python command itself).
SHELL := /bin/bash

# Defaults (each can be given as NAME=VALUE on the command line).
PYTHON ?= python3
VENV ?= .venv
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
CHECKPOINTS ?= checkpoints/$(call given,PRESET)
TEXT ?= a person walks forward and then waves with the right hand
PORT ?= 8000

USER_VARIABLES := PYTHON VENV SOURCE INPUT OUT CLIPS SEED WORKERS ARGS DEMO_SOURCE PRESET \
	DATASET CHECKPOINTS TEXT PORT
# Not exported into the commands' environment: make would expand them to export them.
unexport $(USER_VARIABLES)

# $(call given,NAME): NAME's value as the user wrote it; this file's defaults are expanded.
given = $(if $(filter file default,$(origin $(1))),$($(1)),$(value $(1)))
define newline


endef
# $(call quote,VALUE): VALUE as one single-quoted bash word (each ' written as '\'', each
# newline as $'\n', since make would cut the command line there).
quote = '$(subst $(newline),'$$'\n'',$(subst ','\'',$(1)))'
# $(call arg,NAME): the given value of NAME as one shell word.
arg = $(call quote,$(call given,$(1)))
# The words of ARGS, each quoted.
args = $(foreach word,$(call given,ARGS),$(call quote,$(word)))

VENV_DIR := $(call given,VENV)
STAMP := $(VENV_DIR)/.installed
py = $(call quote,$(VENV_DIR)/bin/python)

.PHONY: install test lint dataset contact-sheet train-ae train-len train-t2m train-eval train \
	sample eval demo bench serve mocap-check mocap-bench

install: $(STAMP)

# A VENV that is a link (to another checkout's environment) is refused: installing this checkout
# editable into it would silently point that other checkout's commands at this code.
# pip byte-compiles the modules it installs (about 14,000 files, most of them torch's) one at a
# time; --no-compile and then compileall on every core does the same work in less time (fresh
# venv on an idle 2-core AMD EPYC Zen 5, 2026-12-06: 59.5 s -> 19.9 s + 17.4 s). Left to Python
# on first import instead, the test suite's first run took a minute longer (two workers compiling
# the same modules). quiet=2: a file that does not compile (torch ships one in Python 3.12
# syntax) is skipped, as pip skips it.
$(STAMP): setup.cfg pyproject.toml
	@if test -L $(call quote,$(VENV_DIR)); then echo "error: VENV $(VENV_DIR) is a symbolic link; installing into it would point its other users at this checkout: give this checkout its own environment (remove the link, or VENV=DIR)" >&2; exit 2; fi
	test -x $(py) || $(call arg,PYTHON) -m venv $(call arg,VENV)
	$(py) -m pip install -q --no-compile --upgrade pip
	$(py) -m pip install -q --no-compile -e '.[test,onnx]'
	$(py) -c 'import compileall, sysconfig; compileall.compile_dir(sysconfig.get_path("purelib"), quiet=2, workers=0)'
	touch $(call quote,$(STAMP))

# The numerics tests: run a second time with oneDNN and ATen held to AVX2, so that on an AVX-512
# machine they also exercise the kernels of the common AVX2 CPUs (on an AVX2 machine the second
# pass repeats the first). ONNX Runtime has no such switch: tests/test_int8_saturation.py drives
# its int8 products to the clip of the non-VNNI kernels on whatever CPU runs it.
NUMERICS_TESTS := tests/test_onednn.py tests/test_fast_recurrence.py tests/test_temporal_vae.py \
	tests/test_models.py tests/test_speed_paths.py tests/test_release.py \
	tests/test_onnx_backend.py tests/test_int8_saturation.py tests/test_precision_choice.py \
	tests/test_rollouts.py

# The suite runs on TEST_WORKERS processes (pytest-xdist), whole test files to a worker so that
# each module's fixtures are built once; each worker keeps torch to one thread (two workers of two
# threads each oversubscribe two cores, and spinning OpenMP threads then slow everything). The
# tests marked timed (wall-clock bounds) run after it on their own.
TEST_WORKERS ?= 2

test: install
	@$(py) -c 'from t2m.hardware import cpu_description; print("cpu:", cpu_description())'
	OMP_NUM_THREADS=1 $(py) -m pytest -q -n $(call arg,TEST_WORKERS) --dist loadfile -m 'not timed' tests
	$(py) -m pytest -q -p no:cacheprovider -m timed tests
	ONEDNN_MAX_CPU_ISA=AVX2 ATEN_CPU_CAPABILITY=avx2 $(py) -m pytest -q -p no:cacheprovider $(NUMERICS_TESTS)

lint: install
	$(call quote,$(VENV_DIR)/bin/ruff) check .
	$(call quote,$(VENV_DIR)/bin/ruff) format --check .

dataset: install
ifeq ($(call given,SOURCE),synth)
	test -f $(call quote,$(call given,DEMO_SOURCE)/source.json) || $(py) -m dataset_tools synth --out $(call arg,DEMO_SOURCE) --clips $(call arg,CLIPS) --seed $(call arg,SEED) --workers $(call arg,WORKERS)
	$(py) -m dataset_tools build --source joints --input $(call arg,DEMO_SOURCE) --out $(call arg,OUT) --seed $(call arg,SEED) --workers $(call arg,WORKERS) $(args)
else
	$(if $(call given,INPUT),,$(error make dataset SOURCE=$(call given,SOURCE) needs INPUT=DIR (the source files)))
	$(py) -m dataset_tools build --source $(call arg,SOURCE) --input $(call arg,INPUT) --out $(call arg,OUT) --workers $(call arg,WORKERS) $(args)
endif

contact-sheet: install
	$(py) -m dataset_tools contact-sheet --input $(call arg,DEMO_SOURCE) --out $(call quote,$(call given,DEMO_SOURCE)/contact_sheet.png) --clips 12 --seed $(call arg,SEED)

# What every training target passes.
stage_options = --preset $(call arg,PRESET) --dataset $(call arg,DATASET) --checkpoints $(call arg,CHECKPOINTS) $(args)

train-ae: install
	$(py) -m t2m.train autoencoder $(stage_options)

train-len: install
	$(py) -m t2m.train length $(stage_options)

train-t2m: install
	$(py) -m t2m.train generator $(stage_options)

train-eval: install
	$(py) -m t2m.train evaluator $(stage_options)

train: train-ae train-len train-t2m train-eval

sample: install
	$(py) -m t2m.sample --checkpoints $(call arg,CHECKPOINTS) --text $(call arg,TEXT) $(args)

eval: install
	$(py) -m t2m.evaluate --dataset $(call arg,DATASET) --checkpoints $(call arg,CHECKPOINTS) $(args)

demo: install
	$(py) -m t2m.demo $(args)

mocap-check: install
	$(py) -m t2m.evaluate.mocap $(args)

mocap-bench: install
	$(py) -m t2m.evaluate.mocap_bench $(args)

bench: install
	$(py) -m t2m.bench $(args)

serve: install
	$(py) -m t2m.serve --checkpoints $(call arg,CHECKPOINTS) --port $(call arg,PORT) $(args)
