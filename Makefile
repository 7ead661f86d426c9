# Every target builds its own virtualenv first: a fresh clone needs only python3 and make.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: all demo test lint typecheck pytest bench soak clean

all: test

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	# compat: a path entry, so type checkers (mypy, pyright) find the package as well as Python does
	$(BIN)/python -m pip install --quiet -e '.[dev]' --config-settings editable_mode=compat
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/ics35 demo

# The robot layer on the simulator: a 17-joint humanoid on two lines plays a wave (live joint table).
robot-demo: $(STAMP)
	$(BIN)/ics35 play examples/humanoid.toml examples/wave.json

lint: $(STAMP)
	$(BIN)/ruff check ics35_async tests benchmarks

typecheck: $(STAMP)
	$(BIN)/mypy --strict ics35_async

pytest: $(STAMP)
	$(BIN)/pytest --cov=ics35_async --cov-branch --cov-report=term-missing:skip-covered

test: lint typecheck pytest

bench: $(STAMP)
	$(BIN)/python benchmarks/run.py

soak: $(STAMP)
	$(BIN)/python -m benchmarks.soak --json benchmarks/soak_results.json

clean:
	rm -rf $(VENV) .pytest_cache .mypy_cache .ruff_cache .coverage
