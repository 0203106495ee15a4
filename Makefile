# Two entry points: `make demo` (main job on the built-in objects) and `make test`.
# Each creates or refreshes the virtualenv in .venv itself.
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
# The CPU build of torch, when it lies on local disk: then the `train` extra (torch) is installed too.
TORCH_WHEEL := $(wildcard /opt/wheels/torch-2.13.0+cpu-*.whl)
# The GL backend (EGL, else OSMesa) is chosen by simtest itself; set MUJOCO_GL to override it.

.PHONY: venv demo test clean

$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
ifneq ($(TORCH_WHEEL),)
	$(PY) -m pip install -q -e ".[dev,train,pbr,ray]" -c constraints/ci.txt
else
	$(PY) -m pip install -q -e ".[dev,pbr,ray]"
endif
	touch $(STAMP)

venv: $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/simtest demo --out demo_out --resume

test: $(STAMP)
	$(PY) -m pytest -q tests

clean:
	rm -rf $(VENV) demo_out .pytest_cache
