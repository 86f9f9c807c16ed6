# Two commands on a fresh machine: `make demo` (the main job) and `make test` (every test but
# the long ones, which `make test-long` runs; CI runs both).
# Both create .venv when it is missing and install everything the project needs into it.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
export AMENT_PREFIX_PATH := $(abspath $(VENV))
export PYTHONDONTWRITEBYTECODE := 1
# numba's on-disk cache: sim_nodes/jit.py keys ~/.cache/sapga_ros/numba-<digest> by the
# kernel sources, so it is shared between checkouts and never stale
OUT ?= out

.PHONY: demo test test-long bench venv clean

venv: $(STAMP)

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

demo: $(STAMP)
	$(PY) -m sapga_ros.cli.demo --out $(OUT)

test: $(STAMP)
	$(PY) -m pytest -q tests

# the tests marked long (minutes each: 10 recorded launches, the Ray backend, a 60 M-step
# run killed after 40 s); `make test` runs a smaller form of the first and skips the others
test-long: $(STAMP)
	$(PY) -m pytest -q --long -m long tests

bench: $(STAMP)
	$(VENV)/bin/sapga bench
	$(VENV)/bin/sapga bench --ros
	$(VENV)/bin/sapga bench --training

clean:
	rm -rf $(VENV) .cache build install log *.egg-info $(OUT)
