# Reproduce the paper's Table 1, run the tests, set up the environment.
#
#   make               same as `make reproduce`: the full workflow, then results/report.zip
#   make test          pytest on tests/ (unit, schema and the small end-to-end run)
#   make tuning        the tuning grid (config/tuning.yaml: no set of the paper's) in runs/tuning/, runs/tuning-20/, runs/tuning-72/
#   make test-cluster  the small config on a one-node SLURM brought up on this machine
#                      (root; see tests/cluster/run_cluster_test.sh)
#   make venv          the virtual environment $(VENV) from requirements.txt
#   make sysdeps       the Debian packages Mitsuba's LLVM backend and open3d need
#   make report        results/report.zip from an existing run
#   make summary       copy results/summary.md (written by the run) to docs/results/summary.md
#   make unlock        release the lock a killed run left (then `make` resumes it)
#   make lint          snakemake --lint
#   make footprint     the disk and memory the configured run needs, and what this machine lacks
#   make clean         remove results/ (Snakemake's .snakemake/ metadata is kept)
#
# Variables (make VAR=value): VENV, PYTHON, CORES, PYTEST_ARGS,
# SNAKEMAKE_ARGS (extra arguments for every Snakemake call, e.g. -n).

SHELL := /bin/bash
.SHELLFLAGS := -eu -o pipefail -c
.DEFAULT_GOAL := reproduce
.DELETE_ON_ERROR:
.SUFFIXES:

VENV ?= .venv
# The interpreter the venv is made from: python3.11 if there is one, else python3
# (checked to be >= 3.11 when the venv is made).
ifeq ($(origin PYTHON),undefined)
PYTHON := $(or $(shell command -v python3.11 2>/dev/null),$(shell command -v python3 2>/dev/null),python3)
endif
CORES ?= all
PYTEST_ARGS ?=
SNAKEMAKE_ARGS ?=

# The config is the Snakefile's own (config/config.yaml, shape models shipped in
# workflow/resources/shape/): no --config or --configfile is passed here, so that
# one given in SNAKEMAKE_ARGS merges with the file's keys instead of replacing
# another (Snakemake keeps only the last --config and the last --configfile).

# Debian packages: libllvm19 for Mitsuba's LLVM JIT backend (llvm_ad_rgb),
# libusb-1.0-0 because open3d links against it on import.
SYSDEPS := libllvm19 libusb-1.0-0
LIBLLVM := /usr/lib/x86_64-linux-gnu/libLLVM.so.19.1

# Environment of every command that runs the workflow or the tests: the venv
# first on PATH, and Dr.Jit pointed at LLVM 19 unless DRJIT_LIBLLVM_PATH is
# already set. Checked when the command runs, since `sysdeps` may have just
# installed the library.
RUN_ENV := export PATH="$(abspath $(VENV))/bin:$$PATH"; \
	if [ -z "$${DRJIT_LIBLLVM_PATH:-}" ] && [ -e $(LIBLLVM) ]; then export DRJIT_LIBLLVM_PATH=$(LIBLLVM); fi;
SNAKEMAKE := $(VENV)/bin/snakemake --cores $(CORES)
VENV_STAMP := $(VENV)/.requirements.stamp

.PHONY: reproduce tuning test test-cluster venv sysdeps report summary unlock clean lint footprint help

reproduce: sysdeps venv
	$(RUN_ENV) $(SNAKEMAKE) --rerun-incomplete $(SNAKEMAKE_ARGS)
	$(RUN_ENV) $(SNAKEMAKE) --report results/report.zip $(SNAKEMAKE_ARGS)

# The tuning grid, in its own working directory (its results/ under runs/tuning/), so
# that it never mixes with the reproduction's; then the grid at the two ends of the
# images per turn a user may choose: 20 (all its sets, runs/tuning-20/) and 72 (the
# sets of albedo 0.85 at light 5 degrees, runs/tuning-72/).
TUNING := $(SNAKEMAKE) --configfile config/tuning.yaml --rerun-incomplete
tuning: sysdeps venv
	$(RUN_ENV) $(TUNING) --directory runs/tuning $(SNAKEMAKE_ARGS)
	$(RUN_ENV) $(TUNING) --directory runs/tuning-20 --config n_images=20 $(SNAKEMAKE_ARGS)
	$(RUN_ENV) $(TUNING) --directory runs/tuning-72 --config n_images=72 'albedos=[0.85]' 'light_angles_deg=[5]' $(SNAKEMAKE_ARGS)

report: venv
	$(RUN_ENV) $(SNAKEMAKE) --report results/report.zip $(SNAKEMAKE_ARGS)

# The committed copy of the headline numbers, from the run in results/ (the
# README quotes it; tests/test_summary.py checks the quotes against it).
summary:
	@if [ ! -s results/summary.md ]; then \
		echo "error: results/summary.md not found: run the workflow first (make reproduce)" >&2; exit 1; \
	fi
	mkdir -p docs/results
	cp results/summary.md docs/results/summary.md

# A run killed hard (SIGKILL, a lost node, a power cut) leaves Snakemake's lock behind.
unlock: venv
	$(RUN_ENV) $(SNAKEMAKE) --unlock $(SNAKEMAKE_ARGS)

test: sysdeps venv
	$(RUN_ENV) $(VENV)/bin/python -m pytest tests -v --durations=10 $(PYTEST_ARGS)

# Installs and starts munge, slurmctld and slurmd (as root), runs a trimmed
# config/test.yaml locally and through profiles/slurm, compares.
test-cluster: sysdeps venv
	$(RUN_ENV) SNAKEMAKE=$(abspath $(VENV))/bin/snakemake tests/cluster/run_cluster_test.sh

lint: venv
	$(RUN_ENV) $(VENV)/bin/snakemake --lint $(SNAKEMAKE_ARGS)

footprint: venv
	@$(RUN_ENV) $(SNAKEMAKE) -n $(SNAKEMAKE_ARGS) 2>&1 | grep -E "^(estimated footprint|warning: )"

venv: $(VENV_STAMP)

# Redone only when requirements.txt changes (or the venv is removed). An
# existing venv is updated in place, not made anew.
$(VENV_STAMP): requirements.txt
	@if [ -x "$(VENV)/bin/python" ]; then \
		interpreter="$(VENV)/bin/python"; \
	elif [ -n "$(PYTHON)" ] && command -v "$(PYTHON)" >/dev/null 2>&1; then \
		interpreter="$(PYTHON)"; \
	else \
		echo "error: no Python interpreter found (looked for python3.11, then python3)." >&2; \
		echo "       Install Python 3.11 or name one: make venv PYTHON=/path/to/python3.11" >&2; \
		exit 1; \
	fi; \
	if ! "$$interpreter" -c 'import sys; sys.exit(sys.version_info < (3, 11))'; then \
		echo "error: $$interpreter is $$("$$interpreter" --version 2>&1); this workflow needs Python >= 3.11." >&2; \
		echo "       Install Python 3.11 or name one: make venv PYTHON=/path/to/python3.11" >&2; \
		echo "       (if $(VENV) was made with an older Python, remove it first)" >&2; \
		exit 1; \
	fi; \
	if [ ! -x "$(VENV)/bin/python" ]; then \
		echo "Creating $(VENV) with $(PYTHON) ($$("$(PYTHON)" --version 2>&1))"; \
		"$(PYTHON)" -m venv "$(VENV)"; \
	fi
	"$(VENV)/bin/python" -m pip install --disable-pip-version-check --no-input -r requirements.txt
	touch "$@"

sysdeps:
	@missing=""; \
	for package in $(SYSDEPS); do \
		dpkg -s "$$package" >/dev/null 2>&1 || missing="$$missing $$package"; \
	done; \
	if [ -z "$$missing" ]; then \
		echo "sysdeps: $(SYSDEPS) installed"; \
	elif ! command -v apt-get >/dev/null 2>&1; then \
		echo "warning: not a Debian system (no apt-get); install LLVM 19 (libLLVM) and libusb-1.0"; \
		echo "         with your package manager. Without LLVM, Mitsuba falls back to the slow scalar_rgb variant."; \
	elif [ "$$(id -u)" = 0 ]; then \
		echo "sysdeps: installing$$missing"; \
		export DEBIAN_FRONTEND=noninteractive; \
		apt-get update && apt-get install -y --no-install-recommends $$missing; \
	else \
		echo "warning: missing Debian packages:$$missing"; \
		echo "         install them with: sudo apt-get update && sudo apt-get install -y --no-install-recommends$$missing"; \
		echo "         Continuing: without libllvm19 Mitsuba falls back to the slow scalar_rgb variant."; \
	fi

clean:
	rm -rf results/

help:
	@sed -n '2,17s/^# \{0,1\}//p' $(firstword $(MAKEFILE_LIST))
