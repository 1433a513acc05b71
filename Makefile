# msta: two commands on a fresh machine.
#   make demo   create .venv when missing, run the main job on built-in defaults
#   make test   create .venv when missing, run the test suite
SHELL := /bin/bash
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: demo test device-check repro bench bench-sim bench-data bench-train bench-learn bench-deploy bench-scale bench-threads bench-startup venv clean-venv lint docs-terrain hub

venv: $(STAMP)

# Find a Python 3.12: on PATH first, then through pyenv. pyenv shims answer
# `command -v python3.12` even when no 3.12 is selected, so each candidate is run.
$(STAMP): pyproject.toml
	@set -e; PYBIN=""; \
	for c in python3.12 "$$(command -v pyenv >/dev/null 2>&1 && ls -d $$(pyenv root)/versions/3.12*/bin/python3.12 2>/dev/null | sort -V | tail -1)"; do \
	  if [ -n "$$c" ] && "$$c" -c 'import sys; assert sys.version_info[:2] == (3, 12)' >/dev/null 2>&1; then PYBIN="$$c"; break; fi; \
	done; \
	if [ -z "$$PYBIN" ]; then echo "error: msta needs Python 3.12 (lerobot>=0.5 requires it). Install it (e.g. 'pyenv install 3.12') and re-run." >&2; exit 1; fi; \
	echo "using $$PYBIN"; \
	[ -x $(PY) ] || "$$PYBIN" -m venv $(VENV); \
	$(PY) -m pip install --quiet --upgrade pip || { sleep 30; $(PY) -m pip install --quiet --upgrade pip; }; \
	for attempt in 1 2 3; do \
	  $(PY) -m pip install --quiet --resume-retries 20 -e ".[dev]" -e collect/plugins/lerobot_env_msta \
	    -e train/plugins/lerobot_policy_msta && break; \
	  if [ $$attempt -eq 3 ]; then echo "error: pip install failed 3 times (see above); re-run make when the package index answers" >&2; exit 1; fi; \
	  echo "pip install failed (attempt $$attempt of 3, often a dropped download); retrying in 30 s" >&2; sleep 30; \
	done; \
	touch $(STAMP)

demo: $(STAMP)
	MUJOCO_GL=$${MUJOCO_GL:-egl} $(PY) -m msta.eval.apps.demo

test: $(STAMP)
	MUJOCO_GL=$${MUJOCO_GL:-egl} $(PY) -m pytest -q -x -p no:cacheprovider

# The paper's experiments at reference scale (~1 h on 2 cores; resumable: run it again
# after a kill). `make repro SCALE=paper` for the paper's sizes (a GPU machine).
SCALE ?= reference
REPRO_REPORT = $(if $(filter paper,$(SCALE)),docs/reference/paper_scale,docs/reference)
repro: $(STAMP)
	MUJOCO_GL=$${MUJOCO_GL:-egl} $(PY) -m msta.eval.apps.repro --scale=$(SCALE) \
		--output_dir=outputs/repro_$(SCALE) --report_dir=$(REPRO_REPORT)

# The CUDA path of every stage (stage 1 on GPU and CPU, their action parity, one stage-2
# round, msta-eval) sized for a lent GPU machine (~6 min); on a machine without CUDA the
# same stages run on the CPU. Figures: $(DEVICE_OUT)/device_check.json.
DEVICE_OUT ?= $(if $(OUT),$(OUT),outputs)/device_check
device-check: $(STAMP)
	MUJOCO_GL=$${MUJOCO_GL:-egl} $(PY) -m msta.eval.apps.device_check --output_dir=$(DEVICE_OUT)

bench: bench-sim bench-data bench-train bench-learn bench-deploy bench-scale bench-threads bench-startup

bench-sim: $(STAMP)
	$(PY) -m msta.eval.bench.sim

bench-data: $(STAMP)
	$(PY) -m msta.eval.bench.data

bench-train: $(STAMP)
	$(PY) -m msta.eval.bench.train

# Equal wall-clock learning race on one seeded teacher dataset (~9 min): MSTA vs GRU vs MLP.
bench-learn: $(STAMP)
	MUJOCO_GL=$${MUJOCO_GL:-egl} $(PY) -m msta.eval.bench.learn

# Batch-1 latency on one core (~1 min): MSTA paper preset, full and minimized observation,
# eager / TorchScript / onnxruntime, next to the FLOP count and the measured matmul rate.
bench-deploy: $(STAMP)
	$(PY) -m msta.eval.bench.deploy

# Rollout throughput (collect, stage 2, eval) on 1 and 2 Ray workers against the single
# process, round-robin in one run (~5 min on 2 cores); docs/scale.md. Then msta-train's
# samples/s as one process and under torchrun with 1 and 2 processes (~4 min).
bench-scale: $(STAMP)
	MUJOCO_GL=$${MUJOCO_GL:-egl} $(PY) -m msta.eval.bench.scale
	$(PY) -m msta.eval.bench.scale_train

# msta-train's --num_threads default (the cores other work leaves free) against every fixed
# count, on an idle machine and beside busy processes (~5 min on 2 cores).
bench-threads: $(STAMP)
	$(PY) -m msta.eval.bench.threads

# every msta-* --help against a Python importing torch, and msta-train's first line
bench-startup: $(STAMP)
	$(PY) -m msta.eval.bench.startup

docs-terrain: $(STAMP)
	$(PY) -m msta.collect.sim.terrain_docs --docs docs/

# A local Hugging Face-compatible hub for air-gapped labs (see docs/hub.md).
hub: $(STAMP)
	$(VENV)/bin/msta-hub serve --root $${HUB_ROOT:-.hub} --port $${HUB_PORT:-8008} --token-file $${HUB_TOKENS:-.hub-tokens}

lint: $(STAMP)
	$(VENV)/bin/ruff check .

clean-venv:
	rm -rf $(VENV)
