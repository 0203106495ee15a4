# Entry points: `make demo` (the main job on the built-in objects; no torch needed) and `make test` (what CI
# runs). Each creates or refreshes the virtualenv in .venv itself. `make system-packages` (as root) installs the
# Debian/Ubuntu libraries: headless GL for MuJoCo and libLLVM >= 16 for the path tracer's fast variant.
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
BASE := $(VENV)/.installed
TESTS := $(VENV)/.installed-tests
# The CPU build of torch, when it lies on local disk (pinned by constraints/ci.txt so pip takes it).
TORCH_WHEEL := $(wildcard /opt/wheels/torch-2.13.0+cpu-*.whl)
SYSTEM_PACKAGES := libegl1 libgl1 libegl-mesa0 libgl1-mesa-dri libllvm19 chromium
# The GL backend (EGL, else OSMesa) is chosen by simtest itself; set MUJOCO_GL to override it.

.PHONY: venv demo test clean system-packages

# -qq keeps errors and drops setuptools' notice that every flat-layout editable install prints.
# simtest with the path tracer (pbr) and Ray: all that `simtest demo` uses. The shipped networks run with
# ONNX Runtime, so no torch.
$(BASE): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip "setuptools>=77" wheel
	$(PY) -m pip install -qq -e ".[pbr,ray]"
	touch $(BASE)

# The test suite needs the test tools, the train extra (torch, onnx, onnxscript) and the docs extra (MkDocs: the
# tests build the documentation site).
$(TESTS): $(BASE)
ifneq ($(TORCH_WHEEL),)
	@echo "make: installing the dev, train and docs extras, torch from the local CPU wheel $(TORCH_WHEEL)"
	$(PY) -m pip install -qq -e ".[dev,train,pbr,ray,docs]" -c constraints/ci.txt
else
	@echo "make: no local CPU torch wheel in /opt/wheels: installing the train extra with torch from the package index (a large download)"
	$(PY) -m pip install -qq -e ".[dev,train,pbr,ray,docs]"
endif
	touch $(TESTS)

venv: $(BASE)

demo: $(BASE)
	$(VENV)/bin/simtest demo --out demo_out --resume

test: $(TESTS)
	$(PY) -m pytest -q tests

system-packages:
	apt-get update
	apt-get install -y --no-install-recommends $(SYSTEM_PACKAGES)

clean:
	rm -rf $(VENV) demo_out .pytest_cache
