# The two commands of the README: `make demo` (main job) and `make test` (tests). Each sets up
# everything it needs on first use (scripts/setup.sh) and is quick the second time.
VENV ?= .venv
PY := $(VENV)/bin/python
AGENTS ?= 4
SCENE ?= room0
PRESET ?= demo
OUT ?= runs/demo
POLICY ?= always
ALIGNMENT ?= paper
# pytest-xdist processes for `make test` (auto: one per core)
TEST_WORKERS ?= auto

.PHONY: setup demo test bench clean

setup:
	@bash scripts/setup.sh

demo: setup
	$(VENV)/bin/openmulti run --scene $(SCENE) --agents $(AGENTS) --policy $(POLICY) --alignment $(ALIGNMENT) --preset $(PRESET) --out $(OUT)

test: setup
	$(PY) -m pytest tests -n $(TEST_WORKERS) --dist worksteal --durations=15

bench: setup
	$(PY) benchmarks/bench_world.py

clean:
	rm -rf runs .pytest_cache
