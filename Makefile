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

.PHONY: install demo test bench clean

$(STAMP): pyproject.toml
	test -x $(PY) || python3 -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	# torch first, exactly this version: it is the one CPU build pip finds without CUDA packages.
	$(PY) -m pip install -q torch==2.13.0
	$(PY) -m pip install -q -e ".[all,ray,test]"
	touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/riskplan demo --out $(OUT)
	@echo "open $(OUT)/report.html"

test: $(STAMP)
	$(PY) -m pytest -n 2 --dist loadfile -q

bench: $(STAMP)
	for a in robot kinematics collision tissue; do $(VENV)/bin/riskplan bench $$a --json; done

clean:
	rm -rf $(VENV) demo-out .pytest_cache build *.egg-info
