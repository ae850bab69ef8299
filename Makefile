# Tegument's entry points. Every target bootstraps what it needs: a virtual
# environment in .venv (CPython 3.11, bpy 5.0.1, numpy, maturin + zig, pytest),
# the wheel, the extension zip.
#
#   make demo       build everything and run a headless demo bake into out/demo/
#   make test       every test suite: Rust core, the wheel, real Blender
#   make extension  dist/tegument-<version>-linux_x64.zip
#   make bench      benchmarks -> bench/results.json and docs/performance-table.md

SHELL := /bin/bash
PYTHON ?= python3.11
VENV := .venv
PY := $(VENV)/bin/python
VERSION := $(shell sed -n 's/^version = "\(.*\)"/\1/p' Cargo.toml | head -n1)
WHEEL_DIR := dist/wheels
EXTENSION_ZIP := dist/tegument-$(VERSION)-linux_x64.zip
RUST_SOURCES := $(shell find rust -name '*.rs' -o -name 'Cargo.toml' -o -name 'pyproject.toml' -o -name '*.py' -o -name '*.pyi') Cargo.toml
ADDON_SOURCES := $(shell find addon -name '*.py' -o -name '*.toml')

.PHONY: all demo test test-rust test-wheel test-blender extension wheel bench venv clean fuzz api-docs

all: extension

venv: $(VENV)/.stamp
$(VENV)/.stamp: requirements-dev.txt
	@command -v $(PYTHON) >/dev/null || { echo "error: $(PYTHON) not found; Tegument's tests need CPython 3.11 (the Python of bpy 5.0.1)"; exit 1; }
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --disable-pip-version-check -r requirements-dev.txt
	touch $@

wheel: $(WHEEL_DIR)/.stamp
$(WHEEL_DIR)/.stamp: $(VENV)/.stamp $(RUST_SOURCES)
	rm -rf $(WHEEL_DIR)
	# zig links against an older glibc so the wheel really is manylinux_2_28.
	PATH=$(CURDIR)/$(VENV)/bin:$$PATH $(VENV)/bin/maturin build --release --quiet --zig -m rust/python/Cargo.toml --interpreter $(PY) --out $(WHEEL_DIR)
	$(PY) -m pip install --quiet --disable-pip-version-check --force-reinstall --no-deps $(WHEEL_DIR)/tegument-*.whl
	touch $@

extension: $(EXTENSION_ZIP)
$(EXTENSION_ZIP): $(WHEEL_DIR)/.stamp $(ADDON_SOURCES)
	$(PY) tools/build_extension.py --wheels $(WHEEL_DIR) --addon addon --out dist

test: test-rust test-wheel test-blender

test-rust:
	cargo test -p tegument-core

test-wheel: $(WHEEL_DIR)/.stamp
	$(PY) -m pytest rust/python/tests

test-blender: $(EXTENSION_ZIP)
	TEGUMENT_EXTENSION_ZIP=$(EXTENSION_ZIP) $(PY) -m pytest blender_tests

demo: $(EXTENSION_ZIP)
	TEGUMENT_EXTENSION_ZIP=$(EXTENSION_ZIP) $(PY) demo/run_demo.py --out out/demo

bench: $(EXTENSION_ZIP)
	rm -rf bench/results
	cargo bench -p tegument-core
	TEGUMENT_EXTENSION_ZIP=$(EXTENSION_ZIP) $(PY) bench/blender_bench.py --out bench/results
	$(PY) bench/collect.py --results bench/results --json bench/results.json --markdown docs/performance-table.md

fuzz:
	@echo "cargo-fuzz targets arrive with the robustness work (issue 10)"; exit 1

api-docs: $(WHEEL_DIR)/.stamp
	$(PY) tools/gen_api_docs.py --out docs/python-api.md

clean:
	rm -rf dist out target addon/wheels
