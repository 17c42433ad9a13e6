# Two commands a new user needs: `make demo` and `make test`.
VENV    ?= .venv
PY      := $(VENV)/bin/python
STAMP   := $(VENV)/.riskplan-installed
OUT     ?= demo-out
# One thread per process: torch and SciPy share two cores (BoTorch fits run 3-4x slower otherwise).
export OMP_NUM_THREADS ?= 1
export MKL_NUM_THREADS ?= 1
export OPENBLAS_NUM_THREADS ?= 1
export RAY_AUTH_MODE ?= disabled
export MPLBACKEND ?= Agg

.PHONY: install demo test lint bench clean browser docs duplicates

$(STAMP): pyproject.toml
	test -x $(PY) || python3 -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	# torch first, exactly this version: it is the one CPU build pip finds without CUDA packages.
	$(PY) -m pip install -q torch==2.13.0
	$(PY) -m pip install -q -e ".[all,ray,test,docs]"
	# compile the numba kernels once, here, so that no command or test compiles them
	$(VENV)/bin/riskplan warm --workers 2
	touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/riskplan demo --out $(OUT)
	@echo "open $(OUT)/report.html"

test: $(STAMP) browser lint
	# warm the kernel cache first (a second or two when it is warm): an emptied cache is then
	# compiled once, here, instead of by each test worker on its first call
	$(VENV)/bin/riskplan warm --workers 2
	$(PY) -m pytest -n 2 --dist loadfile -q

# ruff (configured in pyproject.toml): lint rules and the formatter; `ruff format src tests` fixes layout.
lint: $(STAMP)
	$(VENV)/bin/ruff check src tests
	$(VENV)/bin/ruff format --check src tests

# Repeated code in src (the measure: at most 4 repeated blocks of >= 6 lines that are not
# boilerplate). `duplicates` is a stand-alone tool, not on PyPI; tests/duplicates_measure.py runs
# it over src and over src with the declarations that must be literal taken out (the boilerplate
# rule, in code), prints both counts and the rows that count. Where the tool is not installed it
# says so instead of failing (docs/architecture.md, "Measures").
duplicates: $(STAMP)
	@$(PY) -m tests.duplicates_measure

# Headless Chromium for the report tests (tests/browser.py). Installed from Debian when missing
# and this runs as root with apt-get; otherwise those tests skip and say why.
browser:
	@if command -v chromium >/dev/null && command -v chromedriver >/dev/null; then :; \
	elif [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
		echo "installing chromium + chromium-driver (Debian) for the report tests"; \
		(apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium chromium-driver) >/dev/null 2>&1 \
			|| echo "could not install chromium: the browser tests will skip"; \
	else echo "chromium not installed and not root: the browser tests will skip"; fi

# The API reference from the docstrings (Sphinx + numpydoc), warnings as errors, no network.
docs: $(STAMP)
	$(VENV)/bin/sphinx-build -q -W --keep-going -b html docs/api build/api
	@echo "open build/api/index.html"

bench: $(STAMP)
	for a in robot kinematics collision tissue; do $(VENV)/bin/riskplan bench $$a --json; done

clean:
	rm -rf $(VENV) demo-out .pytest_cache build *.egg-info
