# Every target builds its own virtualenv first: a fresh clone needs only python3 and make.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
# make demo needs only the package itself (no test, lint or docs tools).
DEMO_STAMP := $(VENV)/.demo-installed

# The tests start a few hundred Python processes (the CLI, pty simulators, example programs).  Where the
# environment says not to write bytecode (PYTHONDONTWRITEBYTECODE), each of them compiles the package's
# modules again: about 0.15 s of CPU a process.  They are written to __pycache__ (ignored by git, left out
# of the wheel and sdist) like the installed packages' own.
export PYTHONDONTWRITEBYTECODE :=

.PHONY: all demo robot-demo screenshots test lint format format-check typecheck pytest pytest-parallel pytest-realtime pytest-compiled compiled docs docs-serve dist bench soak clean browser tools web-demo bench-web stress

all: test

$(STAMP): pyproject.toml setup.py ics35_async/drivers/_burst.c
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	# (A path entry, so type checkers (mypy, pyright) find the package as Python does: package-dir in pyproject.toml.)
	# ICS35_COMPILE=0: the engine stays plain Python here (compiled modules would shadow every edit; see setup.py).
	ICS35_COMPILE=0 $(BIN)/python -m pip install --quiet -e '.[dev,web]'
	$(MAKE) --no-print-directory browser tools
	touch $(STAMP)

# The web configurator's browser tests drive Debian's chromium-headless-shell through Playwright: Chromium's
# own headless build, which Playwright itself uses for headless runs (its browser download is not used); it
# costs the suite a quarter less CPU than the full chromium.  Installed here when missing and we are root on
# a Debian-like machine; otherwise the tests fail, naming what to install (ICS35_CHROMIUM points at another
# Chromium binary, the full browser included).
CHROMIUM ?= /usr/bin/chromium-headless-shell
browser:
	@if [ -x "$${ICS35_CHROMIUM:-$(CHROMIUM)}" ]; then :; \
	elif [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
		apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium-headless-shell; \
	else echo "note: the browser tests need chromium-headless-shell: sudo apt-get install chromium-headless-shell (or set ICS35_CHROMIUM)" >&2; fi

# Programs the tests drive besides Python: socat (a TCP serial bridge in front of the pty simulator).
# Installed here, as root on a Debian-like machine, never by a test; a test that finds one missing
# fails and names this target.
TOOLS := socat
tools:
	@missing=""; for t in $(TOOLS); do command -v $$t >/dev/null || missing="$$missing $$t"; done; \
	if [ -z "$$missing" ]; then :; \
	elif [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
		apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends $$missing; \
	else echo "note: the tests need$$missing: sudo apt-get install$$missing" >&2; fi

# The same editable install as the development one above (a path entry): the demo's replaces it in the same venv.
$(DEMO_STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	ICS35_COMPILE=0 $(BIN)/python -m pip install --quiet -e .
	touch $(DEMO_STAMP)

demo: $(DEMO_STAMP)
	$(BIN)/ics35 demo

# The robot layer on the simulator: a 17-joint humanoid on two lines plays a wave (live joint table).
robot-demo: $(DEMO_STAMP)
	$(BIN)/ics35 play examples/humanoid.toml examples/wave.json

# ruff format is applied to, and checked on, the whole Python tree.
FORMATTED := ics35_async _ics35_async_entry.py tests benchmarks tools setup.py

# The configurator's screenshots in docs/images, taken by its browser tests (a plain test run leaves them alone).
screenshots: $(STAMP) browser
	ICS35_SCREENSHOTS=1 $(BIN)/pytest -q -p no:cacheprovider tests/test_web_browser.py tests/test_web_browser_line.py tests/test_web_browser_servo.py

# The servo configurator in the browser, on the simulator (prints its URL; Ctrl-C stops it).
web-demo: $(STAMP)
	$(BIN)/ics35 web

lint: $(STAMP)
	$(BIN)/ruff check ics35_async _ics35_async_entry.py tests benchmarks tools
	$(BIN)/ruff format --check $(FORMATTED)

format-check: $(STAMP)
	$(BIN)/ruff format --check $(FORMATTED)

format: $(STAMP)
	$(BIN)/ruff format $(FORMATTED)

typecheck: $(STAMP)
	$(BIN)/mypy --strict ics35_async _ics35_async_entry.py tests/support
	MYPYPATH=benchmarks $(BIN)/mypy --strict $(wildcard benchmarks/*.py)
	$(BIN)/mypy --strict --explicit-package-bases benchmarks/soak

# pytest in two passes.  First everything but the real-time tests on PYTEST_WORKERS processes (pytest-xdist):
# most of a test's time is spent waiting on a simulated line or a subprocess, not computing, so three workers a
# core keep the cores busy (with two a core they sat idle a tenth of the pass; more than three a core pay more
# in each worker's start and collection than they fill); --dist loadfile keeps each module on one worker
# (module-scoped servers started once, the browser tests' page walked in order; xdist's loadgroup is not used:
# pytest 9.2 ignores its group names), in the order tests/conftest.py gives them, longest first (xdist would
# reorder them by their count of tests).
# Then the tests marked realtime, on two workers with no other tests beside them: they judge real elapsed time
# (and pass beside two CPU-burning processes: see `make stress`).  One coverage report.
# The second pass collects only the modules that mark a test realtime (collecting every module takes
# seconds); tests/conftest.py stops the run if a realtime test is marked where this list cannot see it.
CORES := $(shell nproc 2>/dev/null || sysctl -n hw.ncpu 2>/dev/null || echo 2)
PYTEST_WORKERS ?= $(shell echo $$(( $(CORES) * 3 > 12 ? 12 : $(CORES) * 3 )))
REALTIME_WORKERS ?= 2
COV := --cov=ics35_async --cov-branch
REALTIME_MODULES = $(shell grep -l "mark\.realtime" tests/test_*.py)
# (browser and tools are checked on every run: a venv made before a tool was added still gets it)
pytest: pytest-parallel
	$(MAKE) --no-print-directory pytest-realtime

pytest-parallel: $(STAMP) browser tools
	$(BIN)/pytest -q --fail-on-skip -n $(PYTEST_WORKERS) --dist loadfile --no-loadscope-reorder -m "not realtime" $(COV) --cov-report=

# (it appends to the parallel pass's coverage data: run alone, its report includes whatever an earlier run left)
pytest-realtime: $(STAMP) browser tools
	$(BIN)/pytest -q --fail-on-skip -n $(REALTIME_WORKERS) --dist loadfile --no-loadscope-reorder -m realtime $(COV) --cov-append \
		--cov-report=term-missing:skip-covered \
		$(REALTIME_MODULES)

# The package as its wheel has it: a copy of the tree (the files git knows, edits included) with the engine's
# rules compiled by mypyc (see setup.py).  The development tree keeps them plain Python.  A build that falls
# back to plain Python (it only warns: users still get a working package) fails here.
COMPILED_TREE := build/compiled
$(COMPILED_TREE)/.built: $(STAMP) setup.py $(wildcard $(shell git ls-files ics35_async tests benchmarks))
	rm -rf $(COMPILED_TREE) && mkdir -p $(COMPILED_TREE)
	git ls-files -co --exclude-standard -z | tar --null -T - --ignore-failed-read -cf - 2>/dev/null | tar -xf - -C $(COMPILED_TREE)
	cd $(COMPILED_TREE) && ICS35_COMPILE=1 $(CURDIR)/$(BIN)/python setup.py -q build_ext --inplace > build.log 2>&1 \
		&& ! grep -q "is not compiled" build.log || { cat build.log; exit 1; }
	touch $@
compiled: $(COMPILED_TREE)/.built

# The tests of what mypyc compiles, on the compiled copy: the engine's rules, the stream, the burst path and
# the contract suite (every driver, loop and port kind).  ICS35_EXPECT_COMPILED=1: a copy whose modules did not
# compile fails (tests/test_compiled_engine.py) rather than testing the plain modules again.
COMPILED_TESTS = tests/test_compiled_engine.py tests/test_engine_*.py tests/test_burst_*.py tests/test_anyio_bursts.py \
	tests/test_contract.py tests/test_fuzz.py tests/test_numeric_types.py tests/test_stream*.py tests/test_group*.py \
	tests/test_bus.py tests/test_public_api.py
pytest-compiled: $(COMPILED_TREE)/.built browser tools
	cd $(COMPILED_TREE) && ICS35_EXPECT_COMPILED=1 $(CURDIR)/$(BIN)/pytest -q -p no:cacheprovider --fail-on-skip \
		-n $(COMPILED_WORKERS) --dist loadfile -m "not realtime" $(wildcard $(COMPILED_TESTS))
COMPILED_WORKERS ?= $(CORES)

# The checks run beside the tests (make -j): lint, types and the compiled pass beside the parallel pass, which
# keeps both cores busy; the docs build (a process on one core for seconds) beside the real-time pass, which
# uses about one (its two workers mostly wait: its tests are judged against the clock).
test: $(STAMP)
	$(MAKE) --no-print-directory -j4 --output-sync=target lint typecheck pytest-parallel pytest-compiled
	$(MAKE) --no-print-directory -j2 --output-sync=target docs pytest-realtime

# Flakiness measured: the whole suite five times in a row under two CPU-burning processes (this target
# starts them and stops them, also on Ctrl-C); fails on the first failing run (its log: build/stress-N.log).
STRESS_RUNS ?= 5
stress: $(STAMP)
	@mkdir -p build; burners=""; trap 'kill $$burners 2>/dev/null' EXIT INT TERM; \
	for n in 1 2; do $(BIN)/python -c "while True: pass" & burners="$$burners $$!"; done; \
	echo "stress: $(STRESS_RUNS) runs of make pytest beside two CPU burners (pids$$burners) on $$(nproc) cores"; \
	for run in $$(seq $(STRESS_RUNS)); do \
		start=$$(date +%s); \
		$(MAKE) --no-print-directory pytest > build/stress-$$run.log 2>&1; code=$$?; \
		echo "stress: run $$run: exit $$code, $$(( $$(date +%s) - start )) s, $$(grep -E '(passed|failed)' build/stress-$$run.log | tail -2 | tr '\n' ' ')"; \
		[ $$code -eq 0 ] || { echo "stress: run $$run failed, see build/stress-$$run.log"; exit 1; }; \
	done; echo "stress: $(STRESS_RUNS) of $(STRESS_RUNS) runs passed"

# The docs site (MkDocs Material + mkdocstrings): warnings, broken links and
# unresolved cross-references fail the build.
# Not --quiet: it hides warnings from --strict too (a broken cross-reference would pass).
docs: $(STAMP)
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict --site-dir build/site

docs-serve: $(STAMP)
	$(BIN)/mkdocs serve

# Wheel and sdist into dist/.
dist: $(STAMP)
	rm -rf dist
	$(BIN)/python -m build --no-isolation --outdir dist

# On the compiled copy (the package as its wheel has it): its modules come first on the path.
bench: $(STAMP) compiled
	PYTHONPATH=$(CURDIR)/$(COMPILED_TREE) $(BIN)/python benchmarks/run.py

# The web configurator's cost: stream rate with the Live plots page open vs none, server CPU per update (about 45 s).
bench-web: $(STAMP)
	$(BIN)/python benchmarks/bench_web.py

# On the compiled copy, run from there (python -m puts the working directory first on the path).
soak: $(STAMP) compiled
	cd $(COMPILED_TREE) && $(CURDIR)/$(BIN)/python -m benchmarks.soak --json $(CURDIR)/benchmarks/soak_results.json

# (also an engine compiled in place by hand, ICS35_COMPILE=1 ... --inplace: it would shadow every edit)
clean:
	rm -rf $(VENV) .pytest_cache .mypy_cache .ruff_cache .coverage build dist
	rm -f ics35_async/_compiled__mypyc.* $(addsuffix .*.so,$(basename $(wildcard ics35_async/engine/*.py)))
