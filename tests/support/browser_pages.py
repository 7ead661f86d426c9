"""What the configurator's browser tests share: a simulated line on a pty, ``ics35 web`` started as a user
starts it, a page on it, and the steps many tests take on it (a scan, a servo's page opened and read).

The ``browser`` fixture (headless Chromium driven by Playwright, one per test module) is in ``tests/conftest.py``.
"""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

from playwright.sync_api import Browser, Page, expect

from tests.support.pty_line import PtyLine
from tests.support.timing import GUARD, PATIENT_OPTION, scaled

CHROMIUM = os.environ.get("ICS35_CHROMIUM", "/usr/bin/chromium-headless-shell")  # see the Makefile's browser target
CHROMIUM_ARGS = [
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
]  # fmt: skip
ROOT = Path(__file__).resolve().parents[2]
IMAGES = ROOT / "docs" / "images"
KEEP_SHOTS = os.environ.get("ICS35_SCREENSHOTS") == "1"
WEB = [sys.executable, "-m", "ics35_async.cli", "web", "--no-browser"]
WAIT_MS = int(scaled(20.0) * 1000)  # a busy machine: every wait is for an outcome, never a measure of speed
# A scan (or a renumbering's survey, which probes every ID too) with the patient allowance: a reply late
# past a probe's short wait (a loaded machine) has it probe every silent ID again with the full half
# second, so it can take half a minute.
SCAN_WAIT_MS = int(scaled(60.0) * 1000)
# How soon the server switches off the motion of a page that is gone: at once for a tab closed (its socket
# closes), a few seconds for one whose network went (no answer to the server's pings).
PAGE_GONE_BOUND = scaled(8.0)
expect.set_options(timeout=WAIT_MS)


def shot(page: Page, name: str, height: int = 1000, width: int = 1280) -> None:
    """The page from its top, ``height`` pixels of it (the header stays put while the page scrolls);
    into docs/images with ICS35_SCREENSHOTS=1."""
    size = page.viewport_size
    page.set_viewport_size({"width": width, "height": height})
    page.keyboard.press("Home")  # the page allows no eval (CSP): scrolled the way a person would
    page.locator("main h1:visible").scroll_into_view_if_needed()
    picture = page.screenshot()
    assert picture.startswith(b"\x89PNG")
    if KEEP_SHOTS:
        IMAGES.mkdir(parents=True, exist_ok=True)
        (IMAGES / f"web-{name}.png").write_bytes(picture)
    if size is not None:
        page.set_viewport_size(size)


SCAN_OUTCOME = {"scan summary": "#scan-summary", "message": "#message", "line": "#line-status"}


def scan_finds(p: Page, count: int, ids: str = "") -> None:
    """Scan the line from ``p``'s Line page (``ids``: the IDs to ask, as typed; all 32 if empty): ``count``
    servos found and listed.  A failure says what the page showed (the scan's summary, the message box, the
    line's status), not only that the table stayed empty."""
    p.fill("#scan-ids", ids)
    p.click("#scan-btn")
    scan_lists(p, count)


def scan_lists(p: Page, count: int) -> None:
    """The scan under way on ``p``'s Line page ends with ``count`` servos found and listed (a failure says
    what the page showed)."""
    try:
        expect(p.locator("#scan-summary")).to_contain_text(f"{count} servo(s) found", timeout=SCAN_WAIT_MS)
        expect(p.locator("#servo-table tbody tr")).to_have_count(count)
    except AssertionError as exc:
        shown = {name: p.locator(sel).text_content() for name, sel in SCAN_OUTCOME.items()}
        raise AssertionError(f"a scan did not list {count} servos; the page showed {shown}") from exc


def base_of(url: str) -> str:
    return url.split("/?")[0]


def servo_read(p: Page, sid: int) -> None:
    """Wait until ``p``'s Servo page says it has read servo ``sid`` (its reads done: its buttons act on it).  (Its
    tables fill before the last read, and could be the page's last visit's.)"""
    expect(p.locator(f"#page-servo[data-loaded='{sid}']")).to_be_attached()


def until(condition: Callable[[], bool], failure: str) -> None:
    """Wait for what the simulated line shows (only against a hang: GUARD)."""
    deadline = time.monotonic() + GUARD
    while not condition():
        assert time.monotonic() < deadline, failure
        time.sleep(0.01)


def until_on(page: Page, condition: Callable[[], bool], failure: str) -> None:
    """Wait for what the page's own events do (a route's handler): Playwright runs them only inside its own calls,
    so the wait is the page's (:func:`until` sleeps, and a request the page made after a click went unseen)."""
    deadline = time.monotonic() + GUARD
    while not condition():
        assert time.monotonic() < deadline, failure
        page.wait_for_timeout(20)


def backed_up(page: Page, folder: Path) -> Path:
    """The Servo page's **Back up to a file**, its download saved in ``folder`` under the name it was offered."""
    with page.expect_download() as download:
        page.click("#backup-btn")
    backup = folder / download.value.suggested_filename
    download.value.save_as(backup)
    return backup


def open_servo_page(page: Page, servo_id: int) -> None:
    """The Servo page of ``servo_id``, its reads done (see :func:`servo_read`; its ID in the EEPROM table, then its
    RAM shown)."""
    page.goto(page.url.split("#")[0] + f"#servo/{servo_id}")
    servo_read(page, servo_id)
    expect(page.locator("#eeprom-table [name=servo_id]")).to_have_value(str(servo_id))
    expect(page.locator("#ram-table tbody tr").first).to_be_visible()


def stop_servers(*procs: subprocess.Popen[str] | None) -> None:
    """Stop ``ics35 web`` processes a test started itself (``None``: one it did not get to start)."""
    for proc in procs:
        if proc is not None:
            proc.terminate()
            proc.wait(10)
            assert proc.stdout is not None
            proc.stdout.close()


@contextlib.contextmanager
def web_server_page(
    browser: Browser, line: PtyLine, args: list[str] | None = None, *, timezone_id: str | None = None
) -> Iterator[Page]:
    """``ics35 web ARGS`` (by default ``--port`` ``line``'s pty) in a process of its own and a page on it (a
    browser in ``timezone_id``, when given); at the end the server is stopped and ``line`` closed, and the server
    must have printed no traceback."""
    proc = subprocess.Popen(
        [*WEB, *(["--port", line.path] if args is None else args), *PATIENT_OPTION],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "ICS35_WEB_TOKEN": ""},
    )
    assert proc.stdout is not None and proc.stderr is not None
    context = browser.new_context(timezone_id=timezone_id)
    try:
        page = context.new_page()
        page.set_default_timeout(WAIT_MS)
        page.goto(proc.stdout.readline().strip())
        yield page
    finally:
        context.close()
        proc.terminate()
        proc.wait(10)
        errors = proc.stderr.read()
        proc.stdout.close()
        proc.stderr.close()
        line.close()
    assert "Traceback" not in errors, errors
