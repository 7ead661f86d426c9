# Every target builds its own virtualenv first: a fresh clone needs only python3 and make.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: all demo test lint typecheck pytest bench soak clean browser web-demo bench-web

all: test

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev,web]'
	$(MAKE) --no-print-directory browser
	touch $(STAMP)

# The web configurator's browser tests drive Debian's chromium through Playwright (Playwright's own
# browser download is not used).  Installed here when missing and we are root on a Debian-like
# machine; otherwise the tests fail, naming what to install (ICS35_CHROMIUM points at another binary).
CHROMIUM ?= /usr/bin/chromium
browser:
	@if [ -x "$${ICS35_CHROMIUM:-$(CHROMIUM)}" ]; then :; \
	elif [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
		apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium; \
	else echo "note: the browser tests need chromium: sudo apt-get install chromium (or set ICS35_CHROMIUM)" >&2; fi

demo: $(STAMP)
	$(BIN)/ics35 demo

# The robot layer on the simulator: a 17-joint humanoid on two lines plays a wave (live joint table).
robot-demo: $(STAMP)
	$(BIN)/ics35 play examples/humanoid.toml examples/wave.json

# The servo configurator in the browser, on the simulator (prints its URL; Ctrl-C stops it).
web-demo: $(STAMP)
	$(BIN)/ics35 web

lint: $(STAMP)
	$(BIN)/ruff check ics35_async tests benchmarks

typecheck: $(STAMP)
	$(BIN)/mypy --strict ics35_async

pytest: $(STAMP)
	$(BIN)/pytest --cov=ics35_async --cov-branch --cov-report=term-missing:skip-covered

test: lint typecheck pytest

bench: $(STAMP)
	$(BIN)/python benchmarks/run.py

# The web configurator's cost: stream rate with the Live plots page open vs none, server CPU per update (~25 s).
bench-web: $(STAMP)
	$(BIN)/python benchmarks/bench_web.py

soak: $(STAMP)
	$(BIN)/python -m benchmarks.soak --json benchmarks/soak_results.json

clean:
	rm -rf $(VENV) .pytest_cache .mypy_cache .ruff_cache .coverage
