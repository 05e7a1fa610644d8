# kdray: every target does its own set-up (a virtual environment from pyproject.toml).
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed-$(shell cksum pyproject.toml | cut -d' ' -f1)
SCENE ?= scenes/cornell.obj
CAMERA ?= scenes/cornell.json
OUT ?= out

.PHONY: install render test test-runtimes test-long bench bench-all bench-deps bench-build bench-trace golden clean

install: $(STAMP)

$(STAMP): pyproject.toml
	$(PY) -m venv $(VENV)
	@# pyproject.toml's build-system requirements too: tests/test_wheel.py builds a wheel offline
	$(BIN)/python -m pip install -q --upgrade pip 'setuptools>=77' wheel
	$(BIN)/python -m pip install -q -e '.[test]'
	@# the tree builder (numba, into kdray/builder/__pycache__) and a default render's
	@# kernels on the default device, compiled once here rather than in the first render;
	@# on Linux, kdray's copy of Intel's CPU runtime (.venv/lib/kdray-intel-cpu-*: kdray.runtimes)
	$(BIN)/kdray setup
	rm -f $(VENV)/.installed-*
	touch $@

# Render the default scene: out/cornell.exr and a PNG preview.
render: $(STAMP)
	mkdir -p $(OUT)
	$(BIN)/kdray render $(SCENE) --camera $(CAMERA) -o $(OUT)/cornell.exr --preview $(OUT)/cornell.png

# The test suite: tests/test_runtimes.py on every OpenCL implementation that works here,
# the rest on the default device; the summary says which were covered. On 2 cores (a
# Zen 4 where Intel's CPU runtime and Oclgrind work): about 3.5 minutes from a fresh
# clone, whose ~180 kernel programs compile first (Intel's runtime: about 1.8 s a
# program with packets; most of the time), less once they are in pyopencl's compiler
# cache (~/.cache/pyopencl; a change to kernels/ compiles them again). Long checks are
# `make test-long`: every work size and both scenes, packets of the other width, more
# scales and leaf rules, the builder compiled from nothing, 10,000 fuzz cases.
# One pytest process a core (at most 8), each test file in one process: a file's tests
# share their kernel programs, which are compiled once a process (pytest-xdist).
PARALLEL ?= -n auto --maxprocesses 8 --dist loadfile

test: $(STAMP)
	$(BIN)/python -m pytest -q -m "not slow" $(PARALLEL)

# The whole matrix: every kernel test on each working CPU or GPU implementation in turn
# (PYOPENCL_CTX), and Oclgrind's small cases (tests/test_runtimes.py).
KERNEL_TESTS ?= tests/test_trace.py tests/test_build.py tests/test_accuracy.py tests/test_golden.py \
	tests/test_cull.py tests/test_device_layout.py tests/test_runtimes.py tests/test_refine.py \
	tests/test_scale.py tests/test_double.py
test-runtimes: $(STAMP)
	@set -e; for rt in $$($(BIN)/python -c "from kdray.device import working_devices; \
	  print(' '.join(dict.fromkeys(i for _, _, i in working_devices(include_simulators=False))))"); do \
	  echo "== kernel tests on $$rt"; \
	  PYOPENCL_CTX=$$rt KDRAY_TEST_RUNTIMES=$$rt $(BIN)/python -m pytest -q -m "not slow" $(KERNEL_TESTS); \
	done
	@echo "== Oclgrind's cases"; KDRAY_TEST_RUNTIMES=oclgrind $(BIN)/python -m pytest -q tests/test_runtimes.py

test-long: $(STAMP)
	$(BIN)/python -m pytest -q -m slow $(PARALLEL)

bench-build: $(STAMP)
	$(BIN)/python bench/bench_build.py

# Open3D's wheel needs the system library libusb-1.0: installed here when we may.
bench-deps: $(STAMP)
	$(BIN)/python -m pip install -q -e '.[bench]'
	@ldconfig -p | grep -q libusb-1.0 || { [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null && \
	  (apt-get install -y -q libusb-1.0-0 || (apt-get update -q && apt-get install -y -q libusb-1.0-0)); } || \
	  echo "note: Open3D needs libusb-1.0 (apt-get install libusb-1.0-0); it is left out of the comparison"
	@# Embree's own C++ API, the anchor of bench/bench_embree.py (g++, libembree-dev, libtbb-dev)
	@[ -e /usr/include/embree3/rtcore.h ] && command -v g++ >/dev/null || { [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null && \
	  (apt-get install -y -q g++ libembree-dev libtbb-dev || (apt-get update -q && apt-get install -y -q g++ libembree-dev libtbb-dev)); } || \
	  echo "note: Embree's C++ anchor needs g++, libembree-dev and libtbb-dev; it is left out of the comparison"

# Speed against Open3D, Mitsuba 3 and embreex on the same rays (1024x1024, the bunny and
# a 1.6M-triangle mesh, with the ratios of issue 6's two workflows against Open3D and
# issue 20's against Mitsuba), then bench/bench_error.py: error against run time for
# kdray's settings and the peers; then bench/bench_queries.py: the ray queries beside
# Open3D's and trimesh+embreex's, and their wrong answers; then bench/bench_embree.py:
# incoherent, ambient-occlusion and camera rays against Embree's own C++ API (compiled
# here), beside Open3D and Mitsuba, with any-hit queries against rtcOccluded1.
BENCH_MESHES ?= bunny,bunny-1.6M
bench-trace: bench-deps
	$(BIN)/python bench/bench_trace.py --meshes $(BENCH_MESHES)

bench: bench-deps
	mkdir -p $(OUT)
	$(BIN)/python bench/bench_trace.py --meshes $(BENCH_MESHES)
	$(BIN)/python bench/bench_error.py --plot $(OUT)/bench.png --csv $(OUT)/bench.csv
	$(BIN)/python bench/bench_queries.py --meshes $(BENCH_MESHES)
	$(BIN)/python bench/bench_embree.py --meshes $(BENCH_MESHES) --occluded

# The rest of BENCHMARKS.md's tables that a script makes whole: the above, the stiff
# cases beside Open3D and embreex, build scaling to 6M triangles, what leaving out
# saves, the cold start, datasets (views per second beside Open3D, per-scene overhead,
# Dask workers), calls after an idle moment, small calls, the point queries beside
# Open3D, Warp and trimesh, and rays with thousands of hits beside Open3D. The others
# (lidar, camera models, first calls, SAH costs, wide nodes, A/B runs in turns) have
# their own commands there.
bench-all: bench
	$(BIN)/python bench/bench_points.py
	$(BIN)/python bench/bench_stiff.py
	$(BIN)/python bench/bench_build.py
	$(BIN)/python bench/bench_leave_out.py
	$(BIN)/python bench/bench_cold.py
	$(BIN)/python bench/bench_dataset.py
	$(BIN)/python bench/bench_idle.py
	$(BIN)/python bench/bench_small_calls.py
	$(BIN)/python bench/bench_long_lists.py

# Regenerate the golden images on purpose (review the diff before committing).
golden: $(STAMP)
	$(BIN)/python tests/make_golden.py

clean:
	rm -rf $(VENV) $(OUT) .pytest_cache build *.egg-info
