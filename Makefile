# Two commands on a fresh machine: `make demo` (the main job) and `make test` (every test but
# the long ones, which `make test-long` runs; CI runs both).
# Both create .venv when it is missing and install everything the project needs into it.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
WARM := $(VENV)/.warm
KERNELS := $(shell grep -rl --include='*.py' '@kernel' sim_nodes sapga_ros 2>/dev/null)
export AMENT_PREFIX_PATH := $(abspath $(VENV))
export PYTHONDONTWRITEBYTECODE := 1
# numba's on-disk cache (~/.cache/sapga_ros/numba-<digest>, sim_nodes/jit.py): the digest of
# the kernel sources keeps an edited kernel from running stale code; numba itself keys each
# entry by the source file's path and time, so every checkout compiles once, here in
# `make venv` (sapga_ros.training.warm), not in the first command
OUT ?= out
# pytest-xdist workers of `make test` / `make test-long`: each test process claims its own
# ROS domains (tests/domains.py), so workers never hear each other
TEST_JOBS ?= 2

.PHONY: demo test test-long stress-ros bench venv clean

venv: $(WARM)

$(VENV)/.requirements: requirements.txt
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --disable-pip-version-check --upgrade pip
	$(PY) -m pip install --quiet --disable-pip-version-check -r requirements.txt
	touch $@

# sim_nodes/models: a model module added or removed changes the <model>_sim executables
$(STAMP): $(VENV)/.requirements setup.py setup.cfg package.xml resource/sapga_ros \
		sim_nodes/models $(shell find msg_configs -name '*.yaml' -o -name '*.yml' -o -name '*.json' \
		2>/dev/null)
	$(PY) -m pip install --quiet --disable-pip-version-check --no-deps --no-build-isolation -e .
	touch $(STAMP)

# every kernel compiled into numba's cache for this checkout (again when a kernel changes)
$(WARM): $(STAMP) sim_nodes/jit.py $(KERNELS)
	$(PY) -m sapga_ros.training.warm
	touch $(WARM)

demo: $(WARM)
	$(PY) -m sapga_ros.cli.demo --out $(OUT)

# ~1050 tests in TEST_JOBS pytest-xdist workers (README.md says what it took, measured)
test: $(WARM)
	$(PY) -m pytest -q -n $(TEST_JOBS) --dist worksteal tests

# the tests marked long (minutes each: 10 recorded launches, the Ray backend, a 60 M-step
# run killed after 40 s); `make test` runs a smaller form of the first and skips the others
test-long: $(WARM)
	$(PY) -m pytest -q -n $(TEST_JOBS) --dist worksteal --long -m long tests

# the ROS test files STRESS_RUNS times in a row beside 2 busy loops (tests/stress_ros.py)
STRESS_RUNS ?= 20
stress-ros: $(WARM)
	$(PY) tests/stress_ros.py --runs $(STRESS_RUNS) --jobs $(TEST_JOBS) --out $(OUT)/stress-ros

bench: $(WARM)
	$(VENV)/bin/sapga bench
	$(VENV)/bin/sapga bench --ros
	$(VENV)/bin/sapga bench --training

clean:
	rm -rf $(VENV) .cache build install log *.egg-info $(OUT)
