# Tegument's entry points. Every target bootstraps what it needs: a virtual
# environment in .venv (CPython 3.11, bpy 5.0.1, numpy, maturin + zig, pytest),
# the wheel, the extension zip.
#
#   make demo       build everything and run a headless demo bake into out/demo/
#   make docs-pictures  the demo, then its pictures into docs/images
#   make test       every test suite: Rust core, the wheel, real Blender
#   make extension  dist/tegument-<version>-linux_x64.zip
#   make bench      every benchmark -> bench/results.json, docs/performance-table.md, docs/images/benchmark.png
#   make fuzz       cargo-fuzz targets (mesh topology, CCD), 60 s each; not part of CI

SHELL := /bin/bash
PYTHON ?= python3.11
VENV := .venv
PY := $(VENV)/bin/python
VERSION := $(shell sed -n 's/^version = "\(.*\)"/\1/p' Cargo.toml | head -n1)
WHEEL_DIR := dist/wheels
EXTENSION_ZIP := dist/tegument-$(VERSION)-linux_x64.zip
# rust/fuzz is not part of the wheel (and its target/ is large): left out.
RUST_SOURCES := $(shell find rust -path rust/fuzz -prune -o \( -name '*.rs' -o -name 'Cargo.toml' -o -name 'pyproject.toml' -o -name '*.py' -o -name '*.pyi' \) -print) Cargo.toml
# The .js is the Flamenco job type the extension ships (addon/farm/tegument_bake.js).
ADDON_SOURCES := $(shell find addon -name '*.py' -o -name '*.toml' -o -name '*.js')

.PHONY: all demo docs-pictures test test-rust test-wheel test-blender extension wheel bench venv clean fuzz api-docs

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
	$(PY) -m pytest rust/python/tests testkit

test-blender: $(EXTENSION_ZIP)
	TEGUMENT_EXTENSION_ZIP=$(EXTENSION_ZIP) $(PY) -m pytest blender_tests

demo: $(EXTENSION_ZIP)
	TEGUMENT_EXTENSION_ZIP=$(EXTENSION_ZIP) $(PY) demo/run_demo.py --out out/demo

# The demo's pictures in docs/images (palette PNGs, small enough for the repository).
docs-pictures: demo
	$(PY) tools/docs_pictures.py --demo out/demo --out docs/images

# One run of every benchmark, then one table (bench/run_all.py says what runs and
# records the machine's load per step); about 3 minutes on 2 idle cores.
bench: $(EXTENSION_ZIP)
	rm -rf bench/results
	$(PY) bench/run_all.py --zip $(EXTENSION_ZIP) --results bench/results --json bench/results.json --markdown docs/performance-table.md --plot docs/images/benchmark.png

# cargo-fuzz targets of the core (rust/fuzz, its own workspace: CI never builds
# it). Needs the nightly toolchain and `cargo install cargo-fuzz`. Each target
# runs FUZZ_SECONDS; findings land in rust/fuzz/artifacts/<target>/.
FUZZ_SECONDS ?= 60
FUZZ_TARGETS := topology ccd
fuzz:
	@command -v cargo-fuzz >/dev/null || { echo "error: cargo-fuzz is missing: cargo install cargo-fuzz"; exit 1; }
	@rustup toolchain list | grep -q nightly || { echo "error: cargo-fuzz needs a nightly toolchain: rustup toolchain install nightly"; exit 1; }
	cargo +nightly fuzz build --fuzz-dir rust/fuzz
	set -e; for target in $(FUZZ_TARGETS); do \
		mkdir -p rust/fuzz/corpus/$$target; \
		cargo +nightly fuzz run --fuzz-dir rust/fuzz $$target rust/fuzz/corpus/$$target -- -max_total_time=$(FUZZ_SECONDS) -rss_limit_mb=2048 -timeout=10 -len_control=0; \
	done

api-docs: $(WHEEL_DIR)/.stamp
	$(PY) tools/gen_api_docs.py --out docs/python-api.md

clean:
	rm -rf dist out target addon/wheels
