"""The fixtures every test module shares, found by pytest by name.

* ``cli``: ``cli(*args, stdin="")`` runs ``ics35`` in this process and returns a
  :class:`~tests.support.cli_runs.CliResult` (exit code, stdout, stderr);
* ``cli_process``: ``cli_process(*args, stdin="", timeout=60)`` runs it as a real process
  (:func:`~tests.support.cli_runs.run_process`);
* ``sim_line``: ``sim_line(servos, **VirtualLine options)`` a named in-process simulated line and its
  ``sim://NAME`` URL, closed after the test;
* ``pty_sim``: ``pty_sim(*server args)`` the simulator served on a pty by a subprocess, stopped after the test;
* ``browser``: headless Chromium driven by Playwright, one per test module (the configurator's browser tests;
  what they share besides is :mod:`tests.support.browser_pages`);
* ``anyio_backend``: the async library an ``async def`` test runs on (anyio's pytest plugin runs every
  coroutine test); asyncio unless the test is marked :data:`every_backend`.

Timing: the one profile is :mod:`tests.support.timing` (``ICS35_TEST_TIME_SCALE`` scales it); Hypothesis
runs without its per-example deadline.
Markers (``pyproject.toml``): ``slow``, ``pty`` and ``realtime``; see the testing section of CONTRIBUTING.md.
"""

from __future__ import annotations

import contextlib
import functools
import itertools
import os
import re
import signal
import subprocess
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

import coverage
import pytest
import uvloop
from hypothesis import HealthCheck, settings

from ics35_async.sim import VirtualLine, start_subprocess, stop_subprocess
from tests.support.cli_runs import CliResult, run_in_process, run_process

if TYPE_CHECKING:
    from playwright.sync_api import Browser

# Property tests run without Hypothesis' per-example deadline (200 ms) and its too-slow check: a test never
# asserts that something was fast, and on a loaded machine one example can take longer than that.
settings.register_profile("suite", deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.load_profile("suite")


def pytest_configure(config: pytest.Config) -> None:
    """Ctrl-C and a hang-up as a terminal gives them, however the suite was started.  A shell without job control
    starts a background command with SIGINT ignored, and that is inherited: the Ctrl-C tests (a SIGINT to a
    subprocess or to this process, ``_thread.interrupt_main``) would then test nothing and wait forever."""
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    # nohup (or a service manager) starts it with SIGHUP ignored, and every program a test starts inherits that: the
    # tests of a hang-up (a terminal closed on a command) then wait out their timeouts and fail.  A handler that does
    # nothing keeps the suite's processes going on a hang-up, as nohup asked, and the programs they start get the
    # default (an exec resets a handled signal, never an ignored one).  pytest-xdist's workers start with the
    # default: the environment tells them.
    if signal.getsignal(signal.SIGHUP) is signal.SIG_IGN or os.environ.get(_HANG_UP_IGNORED):
        os.environ[_HANG_UP_IGNORED] = "1"
        signal.signal(signal.SIGHUP, _hang_up_ignored)


_HANG_UP_IGNORED = "ICS35_TEST_SUITE_IGNORES_SIGHUP"


def _hang_up_ignored(signum: int, frame: object) -> None:
    """SIGHUP to the suite's own process: nothing (see pytest_configure)."""


# The async libraries a test can run on, as anyio's plugin names them: asyncio on its default loop and on
# uvloop, and trio.
BACKENDS: dict[str, object] = {
    "asyncio": "asyncio",
    "uvloop": ("asyncio", {"loop_factory": uvloop.new_event_loop}),
    "trio": "trio",
}

every_backend = pytest.mark.parametrize("anyio_backend", list(BACKENDS), indirect=True)


@pytest.fixture(scope="module")
def anyio_backend(request: pytest.FixtureRequest) -> object:
    """asyncio by default; ``@every_backend`` (or an indirect parametrization by name) picks another."""
    return BACKENDS[getattr(request, "param", "asyncio")]


@pytest.fixture(scope="module")
def browser() -> Iterator[Browser]:
    """Headless Chromium for a module's tests (each module its own: `make test` runs the browser modules side by
    side).  Playwright is imported here, not at the top: only the browser tests need it."""
    from playwright.sync_api import sync_playwright

    from tests.support.browser_pages import CHROMIUM, CHROMIUM_ARGS

    if not Path(CHROMIUM).exists():
        pytest.fail(
            f"{CHROMIUM} is missing: `make` installs Debian's chromium-headless-shell (as root), or set ICS35_CHROMIUM"
        )
    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        yield b
        b.close()


@pytest.fixture
def cli(capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> Callable[..., CliResult]:
    """Run ``ics35 ARGS...`` in-process (no port in the environment); optional ``stdin`` text."""
    monkeypatch.delenv("ICS35_PORT", raising=False)
    monkeypatch.delenv("ICS35_BAUD", raising=False)

    def invoke(*args: str, stdin: str = "") -> CliResult:
        return run_in_process(capsys, monkeypatch, *args, stdin=stdin)

    return invoke


@pytest.fixture
def cli_process() -> Callable[..., subprocess.CompletedProcess[str]]:
    """Run ``python -m ics35_async.cli ARGS...`` as a separate process."""
    return run_process


_line_names = itertools.count()


@pytest.fixture
def sim_line() -> Iterator[Callable[..., tuple[VirtualLine, str]]]:
    """``sim_line(servos, **VirtualLine options)`` -> (VirtualLine, its sim://NAME URL); closed after the test."""
    made: list[VirtualLine] = []

    def make(servos: Any = (1, 2, 3), **options: Any) -> tuple[VirtualLine, str]:
        name = f"test-line-{next(_line_names)}"
        options.setdefault("log_size", None)  # keep every transaction: tests read the whole log
        sim = VirtualLine(list(servos), name=name, **options)
        made.append(sim)
        return sim, f"sim://{name}"

    yield make
    for sim in made:
        sim.close()


@dataclass
class PtySim:
    """A simulator server subprocess and the pty it serves."""

    proc: subprocess.Popen[str]
    path: str
    code: int | None = field(default=None)

    def stop(self) -> int:
        """SIGTERM it (a pulled adapter: the pty goes away); its exit code.  Safe to call twice."""
        if self.code is None:
            self.code = stop_subprocess(self.proc)
        return self.code


SIM_NOTES = Path(__file__).resolve().parent.parent / "build" / "pty-sim-notes"


SIM_LAST = ("--last", "24")  # the simulators' notes end with their last reads and writes, timed


@contextlib.contextmanager
def sim_notes(name: str) -> Iterator[TextIO]:
    """``build/pty-sim-notes/NAME.log``, open for a pty simulator's notes (see ``pty_sim``)."""
    SIM_NOTES.mkdir(parents=True, exist_ok=True)
    with open(SIM_NOTES / f"{name}.log", "w", encoding="utf-8") as notes:
        yield notes


@pytest.fixture
def pty_sim(request: pytest.FixtureRequest) -> Iterator[Callable[..., PtySim]]:
    """``pty_sim("--ids", "1-3", ...)`` starts ``python -m ics35_async.sim ARGS``; ``.path`` is its pty.
    Every server still running is stopped after the test, and each must have exited cleanly (0) on
    SIGTERM.  Their notes (what each served, and on exit how many transactions, any bytes no
    client took, and the last reads and writes with their ``time.monotonic()``) go to
    ``build/pty-sim-notes/``, one file per test: when a test fails, they say which side of the pty
    lost what."""
    started: list[PtySim] = []
    with sim_notes(re.sub(r"[^\w.-]+", "_", request.node.nodeid)[-150:]) as notes:

        def start(*args: str) -> PtySim:
            notes.write(f"started with {list(args)}\n")
            notes.flush()
            proc, path = start_subprocess([*args, *SIM_LAST], notes=notes)
            started.append(PtySim(proc, path))
            return started[-1]

        yield start
        codes = [server.stop() for server in started]
    assert codes == [0] * len(started), f"a simulator server did not exit cleanly on SIGTERM: {codes}"


def pytest_itemcollected(item: pytest.Item) -> None:
    """make test's real-time pass collects only the modules whose text marks a test realtime (see the
    Makefile): a realtime test marked elsewhere (a conftest, a helper) would run in neither pass."""
    if item.get_closest_marker("realtime") and "mark.realtime" not in _module_text(item.path):
        raise pytest.UsageError(f"{item.nodeid}: mark realtime tests in their own module (pytest.mark.realtime)")


@functools.cache
def _module_text(path: Path) -> str:
    return path.read_text(encoding="utf-8")


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """A test that starts the pty simulator through ``pty_sim`` is a ``pty`` test without saying so.

    Property tests (hypothesis) run their code hundreds of times, and coverage's tracer makes each pass about
    three times slower, so they run untraced (``no_cover``, as the soaks are marked by hand): what they reach,
    the example tests beside them reach too (the report misses 21 more of 13,400 statements without them).

    The longest modules go first, each kept whole and in its own order: pytest-xdist (``--dist loadfile
    --no-loadscope-reorder``) hands modules to its workers in this order, and a long one handed out last
    would run on alone after the others have finished.  How long a module takes is guessed from its marks
    (:func:`_expected_seconds`)."""
    for item in items:
        if "pty_sim" in getattr(item, "fixturenames", ()):
            item.add_marker(pytest.mark.pty)
        if getattr(getattr(item, "obj", None), "is_hypothesis_test", False):
            item.add_marker(pytest.mark.no_cover)
    weight: dict[Path, float] = {}
    for item in items:
        weight[item.path] = weight.get(item.path, 0.0) + _expected_seconds(item)
    items.sort(key=lambda item: -weight[item.path])  # stable: each module keeps its own order


def _expected_seconds(item: pytest.Item) -> float:
    """A rough guess of a test's time for the order above: a ``slow`` one takes seconds, one across a pty
    (a simulator subprocess, often a CLI one too) about one, the rest (in process) a few hundredths."""
    if item.get_closest_marker("slow"):
        return 5.0
    if item.get_closest_marker("pty"):
        return 1.0
    return 0.05


@contextlib.contextmanager
def _untraced() -> Iterator[None]:
    """No coverage traces inside.  pytest-cov pauses its own coverage for a ``no_cover`` test, but an xdist
    worker runs a second one beneath (started as the plugin loads, before the worker's own), and pausing the
    top one resumes that: so every coverage still tracing is stopped here, innermost, and started again
    after."""
    stopped = []
    while (running := coverage.Coverage.current()) is not None and running not in stopped:
        running.stop()
        stopped.append(running)
    try:
        yield
    finally:
        for running in reversed(stopped):
            running.start()


@pytest.hookimpl(wrapper=True, trylast=True)
def pytest_runtest_call(item: pytest.Item) -> Iterator[object]:
    """A ``no_cover`` test runs untraced under pytest-xdist too."""
    if not item.get_closest_marker("no_cover"):
        return (yield)
    with _untraced():
        return (yield)


@pytest.hookimpl(wrapper=True)
def pytest_collection(session: pytest.Session) -> Iterator[object]:
    """Collection runs untraced: the tracer made each worker's collection about 1 s longer (pytest's own
    calls pay for it too), and what the package runs there is its modules' import.  So every module of the
    package is imported first, traced (its module-level lines count as they would), and the rest of the
    collection runs without the tracer; the tests run traced as ever.  (What collection did beside that, such
    as pytest's probing of module attributes, no longer counts: a test covers a package's lazy names.)"""
    if coverage.Coverage.current() is None:
        return (yield)
    _import_the_package()
    with _untraced():
        return (yield)


def _import_the_package() -> None:
    import importlib
    import pkgutil

    import ics35_async

    for info in pkgutil.walk_packages(ics35_async.__path__, "ics35_async."):
        if info.name.endswith(".__main__"):  # (running it would run the command)
            continue
        with contextlib.suppress(ImportError):  # an optional extra not installed: its own tests say so
            importlib.import_module(info.name)


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption(
        "--fail-on-skip",
        action="store_true",
        help="exit non-zero if any test was skipped (make test: CI must not pass by skipping)",
    )


def pytest_sessionfinish(session: pytest.Session, exitstatus: int) -> None:
    reporter = session.config.pluginmanager.get_plugin("terminalreporter")
    if not session.config.getoption("--fail-on-skip") or reporter is None or hasattr(session.config, "workerinput"):
        return
    skipped = reporter.stats.get("skipped", [])
    if skipped and exitstatus == 0:
        reporter.write_line(f"--fail-on-skip: {len(skipped)} test(s) skipped; every test must run here", red=True)
        session.exitstatus = pytest.ExitCode.TESTS_FAILED
