# VLA-GR: `make demo` runs the main job, `make test` runs the test suite.
# Both set everything up on a fresh machine (idempotent; quick when done).
SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
PIP := $(PY) -m pip
STAMP := $(VENV)/.installed
APT_STAMP := $(VENV)/.apt-installed
APT_PACKAGES := libosmesa6 libegl1 libegl-mesa0 libgl1-mesa-dri ffmpeg chromium
export MUJOCO_GL ?= egl
export PYOPENGL_PLATFORM ?= egl
export HF_HUB_OFFLINE ?= 1

.PHONY: setup apt demo test test-slow lerobot-env lint format bench clean

setup: $(STAMP)

# Headless MuJoCo rendering needs Mesa's EGL/OSMesa, the report's videos ffmpeg (H.264), its
# test headless Chromium. Installed only when running as root on Debian/Ubuntu and not
# already present.
$(APT_STAMP): Makefile
	@mkdir -p $(VENV)
	@if [ "$$(id -u)" = "0" ] && command -v apt-get >/dev/null 2>&1; then \
	  if ! dpkg -s $(APT_PACKAGES) >/dev/null 2>&1; then \
	    echo "installing $(APT_PACKAGES)"; \
	    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $(APT_PACKAGES); \
	  fi; \
	else echo "not root on Debian: make sure $(APT_PACKAGES) (or equivalents) are installed"; fi
	@touch $@

$(STAMP): pyproject.toml constraints.txt $(APT_STAMP)
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PIP) install -q --upgrade pip
	$(PIP) install -q -c constraints.txt torch==2.13.0
	$(PIP) install -q -c constraints.txt -e ".[dev,lerobot,ray,onnx]"
	@touch $@

demo: setup
	$(VENV)/bin/vla-gr demo

test: setup
	$(PY) -m pytest -q -n 2 --dist loadfile

test-slow: setup
	$(PY) -m pytest -q -m slow

# lerobot in a virtualenv of its own (its torch and huggingface-hub pins clash with ours; see
# requirements-lerobot.txt): the slow test loads our LeRobotDataset export with it. ~8 GB.
LEROBOT_VENV := .venv-lerobot
lerobot-env: $(LEROBOT_VENV)/.installed

$(LEROBOT_VENV)/.installed: requirements-lerobot.txt
	@test -x $(LEROBOT_VENV)/bin/python || $(PYTHON) -m venv $(LEROBOT_VENV)
	$(LEROBOT_VENV)/bin/python -m pip install -q -r requirements-lerobot.txt
	@touch $@

lint: setup
	$(VENV)/bin/ruff check src tests benchmarks
	$(VENV)/bin/ruff format --check src tests benchmarks

format: setup
	$(VENV)/bin/ruff check --fix src tests benchmarks
	$(VENV)/bin/ruff format src tests benchmarks

bench: setup
	$(PY) benchmarks/bench_env.py
	$(PY) benchmarks/bench_expert.py --episodes 100 --split val --workers 2 --noise 0,0 --noise 0.2,0.05
	$(PY) benchmarks/bench_heads.py
	$(PY) benchmarks/bench_gr_field.py
	$(PY) benchmarks/bench_train.py
	$(PY) benchmarks/bench_eval.py
	$(PY) benchmarks/bench_navigator.py --split val --first 50 --episodes 100 --plan-every 3 --workers 2
	$(PY) benchmarks/bench_goal_head.py --checkpoint checkpoints/vla_gr_cpu --episodes 60
	$(PY) benchmarks/bench_robustness.py --checkpoint checkpoints/vla_gr_cpu --split test --episodes 100 --workers 2

clean:
	rm -rf $(VENV) $(LEROBOT_VENV) outputs .pytest_cache
