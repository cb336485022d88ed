# procam — the commands of the README: `make demo`, `make test` and `make test-fast`.
# Each creates or refreshes .venv and installs what is missing (system libraries included).

PYTHON ?= python3.11
VENV   ?= .venv
# The CPU wheel of torch is the default; CUDA users override, e.g.
#   make TORCH_SPEC="torch==2.13.0 --index-url https://download.pytorch.org/whl/cu128" demo
TORCH_SPEC ?= torch==2.13.0
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.procam-installed

.PHONY: demo test test-fast venv llvm chromium bench clean-venv

# Passive OpenMP waiting: with spinning threads torch slows down 10-30x when the cores are shared.
demo: venv llvm
	OMP_WAIT_POLICY=PASSIVE $(VENV)/bin/procam demo --out data

# The whole suite, its 15 slowest tests listed: one pytest-xdist worker per core, each test file
# on one worker (its module fixtures built once), files with most tests handed out first (xdist's
# order). Handing out the longest files first was measured no faster on 2 cores (530 s against
# 505 s): the one-test demo module, last in xdist's order, has both cores to itself (104 s), and
# took 154 s beside another long module.
PARALLEL := -n auto --dist loadfile
test: venv llvm chromium
	OMP_WAIT_POLICY=PASSIVE $(PY) -m pytest -q $(PARALLEL) --durations=15

# The inner loop while editing (about 1 minute on 2 cores): the suite without the tests marked slow.
test-fast: venv llvm
	OMP_WAIT_POLICY=PASSIVE $(PY) -m pytest -q $(PARALLEL) -m "not slow" --durations=15

# Speed figures, measured side by side (a few minutes on 2 cores); see benchmarks/results/.
bench: venv llvm
	$(PY) benchmarks/render.py
	OMP_WAIT_POLICY=PASSIVE $(PY) benchmarks/train.py
	$(PY) benchmarks/fidelity.py

venv: $(STAMP)

$(STAMP): pyproject.toml setup.py Makefile
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q $(TORCH_SPEC)
	$(PY) -m pip install -q -e '.[test,ray]'
	@touch $@

# Dr.Jit's LLVM backend needs LLVM >= 16: Debian's libllvm19. Installed when running as root and the
# probe finds no usable LLVM; otherwise procam falls back to the scalar variant with a warning.
llvm: $(STAMP)
	@$(PY) -m sim.variant --ensure-llvm

# The report test renders report.html in headless Chromium: Debian's chromium, installed when
# missing and running as root with apt-get; otherwise that test is skipped and says why.
chromium:
	@if command -v chromium >/dev/null 2>&1; then :; \
	elif [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
		DEBIAN_FRONTEND=noninteractive apt-get update -qq && \
		DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium || \
		echo "procam: installing chromium failed: the report's browser test will be skipped"; \
	else echo "procam: chromium missing and cannot be installed (not root or no apt-get):" \
		"the report's browser test will be skipped"; fi
