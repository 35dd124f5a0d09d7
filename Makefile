# MILLION: two commands do everything on a fresh machine.
#   make test    set up .venv, build the Rust workspace, run every test
#   make train   set up, build, and run the main training job (CONFIG=...)
#   make test-docker  images, 2 env-server containers + the agent, one replica killed
# Other targets: setup, build, serve, lint, bench, tools, clean.

SHELL := /bin/bash
.SHELLFLAGS := -eu -o pipefail -c
ROOT := $(abspath .)
VENV := $(ROOT)/.venv
PYTHON := $(VENV)/bin/python
SYSTEM_PYTHON ?= python3

# tch builds against the libtorch of the torch wheel in .venv (no download).
export PATH := $(VENV)/bin:$(PATH)
export LIBTORCH_USE_PYTORCH := 1
# Where tests and the agent find the env server and the repository.
export MILLION_ROOT := $(ROOT)

CARGO_PROFILE ?= release
CONFIG ?= configs/ml10.toml
ADDRESS ?= 127.0.0.1:50051
PROTO := proto/million/env/v1/env.proto
PY_PROTO_DIR := env-server/src/million_env/_proto

.PHONY: setup build test test-python test-rust test-docker lint serve train bench clean tools

## Set-up: pinned Python packages in .venv, the env server installed editable,
## Python code generated from the proto.
setup: $(VENV)/.installed $(PY_PROTO_DIR)/env_pb2.py

$(VENV)/.installed: requirements/env-server.lock requirements/agent.lock env-server/pyproject.toml
	test -x $(PYTHON) || $(SYSTEM_PYTHON) -m venv $(VENV)
	$(PYTHON) -m pip install --quiet --disable-pip-version-check -r requirements/env-server.lock -r requirements/agent.lock
	$(PYTHON) -m pip install --quiet --disable-pip-version-check --no-deps --no-build-isolation -e env-server
	touch $@

$(PY_PROTO_DIR)/env_pb2.py: $(PROTO) $(VENV)/.installed
	mkdir -p $(PY_PROTO_DIR)
	$(PYTHON) -m grpc_tools.protoc -I proto/million/env/v1 --python_out=$(PY_PROTO_DIR) \
		--pyi_out=$(PY_PROTO_DIR) --grpc_python_out=$(PY_PROTO_DIR) $(PROTO)
	# grpc_tools writes an absolute import; the generated modules live in a package.
	sed -i 's/^import env_pb2 as/from . import env_pb2 as/' $(PY_PROTO_DIR)/env_pb2_grpc.py
	touch $(PY_PROTO_DIR)/__init__.py

build: setup
	cargo build --profile $(CARGO_PROFILE) --workspace --all-targets

test: build test-python test-rust

test-python: setup
	$(PYTHON) -m pytest -q env-server/tests tests/contract tests/deploy tests/lint tests/bench tests/tools

test-rust: build
	cargo nextest run --cargo-profile $(CARGO_PROFILE) --workspace --no-fail-fast

## Containers for real (needs a Docker engine): local base images, the env-server image,
## the agent image from the binary `make build` made, then docker/compose.yaml with 2
## env-server replicas trains configs/quickstart.toml while one replica is killed.
test-docker: build
	docker/test-docker.sh target/$(CARGO_PROFILE)/million

lint: setup
	$(PYTHON) -m ruff check env-server tests docker bench tools
	$(PYTHON) -m ruff format --check env-server tests docker bench tools
	cargo fmt --all --check
	cargo clippy --profile $(CARGO_PROFILE) --workspace --all-targets -- -D warnings
	$(PYTHON) tools/lint_vocabulary.py

serve: setup
	$(VENV)/bin/million-env-server --address $(ADDRESS)

train: build
	target/$(CARGO_PROFILE)/million train --config $(CONFIG)

## Benchmarks (BENCHMARKS.md) through their one entry point, `million bench`:
## make bench BENCH="env --seconds 5"; without BENCH it lists them.
BENCH ?= --help
bench: build
	target/$(CARGO_PROFILE)/million bench $(BENCH)

## Learning tools (tools/*.py: the PPO yardstick, curve plots); see RESULTS.md.
tools: setup
	$(PYTHON) -m pip install --quiet --disable-pip-version-check -r requirements/tools.lock

clean:
	cargo clean
	rm -rf $(VENV) $(PY_PROTO_DIR)
