"""The configurator in a real browser: headless Chromium (Debian's ``chromium``, installed by ``make``)
driven by Playwright, against ``ics35 web`` run as a user runs it, on simulated servos behind a pty.

The simulated line lives in this process (served on a pty by a thread), so
every change the page makes is checked on the simulated servo itself.  Each
page's screenshot is taken; with ``ICS35_SCREENSHOTS=1`` (``make screenshots``)
it goes to ``docs/images/web-*.png``, which the docs show (a plain test run
leaves the tracked pictures alone).
"""

from __future__ import annotations

import contextlib
import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

if not sys.platform.startswith("linux"):
    pytest.skip("the simulated pty and Debian's chromium: Linux only", allow_module_level=True)

from playwright.sync_api import Browser, Page, Request, Route, expect, sync_playwright

from ics35_async.protocol import ReadEeprom
from ics35_async.sim import VirtualLine, VirtualServo
from ics35_async.sim.pty_server import PtyServer
from tests.support.cli_runs import DUMP_ON_USR1
from tests.support.sim_servos import UnplugsWhenAsked
from tests.support.timing import GUARD, PATIENT_OPTION, scaled

CHROMIUM = os.environ.get("ICS35_CHROMIUM", "/usr/bin/chromium-headless-shell")  # see the Makefile's browser target
CHROMIUM_ARGS = [
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
]  # fmt: skip
ROOT = Path(__file__).resolve().parents[1]
IMAGES = ROOT / "docs" / "images"
KEEP_SHOTS = os.environ.get("ICS35_SCREENSHOTS") == "1"
# The tests walk one page in order (a servo opened, then backed up, ...): `make test` hands each module
# whole to one xdist worker (--dist loadfile).
pytestmark = [pytest.mark.slow, pytest.mark.pty]
WEB = [sys.executable, "-m", "ics35_async.cli", "web", "--no-browser"]
WAIT_MS = int(scaled(20.0) * 1000)  # a busy machine: every wait is for an outcome, never a measure of speed
# A scan (or a renumbering's survey, which probes every ID too) with the patient allowance: a reply late
# past a probe's short wait (a loaded machine) has it probe every silent ID again with the full half
# second, so it can take half a minute.
SCAN_WAIT_MS = int(scaled(60.0) * 1000)
expect.set_options(timeout=WAIT_MS)


class PtyLine:
    """A simulated line served on a pty by a thread of this process."""

    def __init__(self, ids: tuple[int, ...], ics36: tuple[int, ...] = ()) -> None:
        self.sim = VirtualLine([VirtualServo(i, ics36=i in ics36) for i in ids])
        self.server = PtyServer(self.sim)
        self.path = str(self.server.open())
        self.thread = threading.Thread(target=self.server.serve, daemon=True)
        self.thread.start()

    def close(self) -> None:
        self.server.stop()
        self.thread.join(5)
        self.server.close()
        self.sim.close()


@pytest.fixture(scope="module")
def lines() -> Iterator[tuple[PtyLine, PtyLine]]:
    two, lone = PtyLine((1, 3), ics36=(3,)), PtyLine((4,))
    yield two, lone
    two.close()
    lone.close()


@pytest.fixture(scope="module")
def server(lines: tuple[PtyLine, PtyLine]) -> Iterator[str]:
    """``ics35 web --port PTY --no-browser``; yields the URL it printed on its first line."""
    proc = subprocess.Popen(
        # --timeout: the simulated servos answer from a thread of this busy process (pytest, Playwright),
        # and on a loaded machine that thread waits for a core for 100 ms and more.  Every present
        # servo must answer (a reply later than the allowance would also teach the line a slow-link
        # extra), yet a scan's 30 empty IDs each wait it out: the patient allowance.
        [*WEB, "--port", lines[0].path, *PATIENT_OPTION],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "ICS35_WEB_TOKEN": ""},
    )
    assert proc.stdout is not None and proc.stderr is not None
    url = proc.stdout.readline().strip()
    try:
        assert re.fullmatch(r"http://127\.0\.0\.1:\d+/\?token=[\w-]{20,}", url), url
        yield url
    finally:
        proc.terminate()
        proc.wait(10)
        errors = proc.stderr.read()
        proc.stdout.close()
        proc.stderr.close()
    assert "Traceback" not in errors, errors


@pytest.fixture(scope="module")
def browser() -> Iterator[Browser]:
    if not Path(CHROMIUM).exists():
        pytest.fail(
            f"{CHROMIUM} is missing: `make` installs Debian's chromium-headless-shell (as root), or set ICS35_CHROMIUM"
        )
    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        yield b
        b.close()


@pytest.fixture(scope="module")
def page(browser: Browser, server: str) -> Iterator[Page]:
    context = browser.new_context(viewport={"width": 1280, "height": 1000}, accept_downloads=True)
    p = context.new_page()
    p.set_default_timeout(WAIT_MS)
    p.goto(server)
    yield p
    context.close()


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


@pytest.fixture(scope="module")
def simulator_server() -> Iterator[str]:
    """``ics35 web --no-browser`` with no port: the built-in simulator."""
    environment = {k: v for k, v in os.environ.items() if k not in ("ICS35_PORT", "ICS35_WEB_TOKEN")}
    proc = subprocess.Popen(
        [sys.executable, "-m", "ics35_async.cli", "web", "--no-browser"],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
        env=environment,
    )
    assert proc.stdout is not None
    yield proc.stdout.readline().strip()
    proc.terminate()
    proc.wait(10)
    proc.stdout.close()


def test_the_built_in_simulator_is_labelled_on_every_page(browser: Browser, simulator_server: str) -> None:
    context = browser.new_context()
    p = context.new_page()
    p.goto(simulator_server)
    for name in ("line", "servo", "id", "many", "live", "traffic"):
        p.click(f"a[href='#{name}']")
        expect(p.locator("#sim-banner")).to_be_visible()
        expect(p.locator("#sim-banner")).to_contain_text("SIMULATOR")
    context.close()


def test_a_stopped_server_is_said_in_words_at_once(browser: Browser) -> None:
    environment = {k: v for k, v in os.environ.items() if k not in ("ICS35_PORT", "ICS35_WEB_TOKEN")}
    proc = subprocess.Popen(
        [sys.executable, "-m", "ics35_async.cli", "web", "--no-browser"],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
        env=environment,
    )
    assert proc.stdout is not None
    context = browser.new_context()
    p = context.new_page()
    # The page's first requests answered: one the stopped server fails would say its own words over the test's.
    with p.expect_response("**/api/ports"), p.expect_response("**/api/status"):
        p.goto(proc.stdout.readline().strip())
    expect(p.locator("#line-status")).to_contain_text("115200 baud")
    proc.terminate()
    proc.wait(10)
    proc.stdout.close()
    expect(p.locator("#message")).to_contain_text("server is gone")
    expect(p.locator("#line-status")).to_have_text("server gone")
    context.close()


def test_a_page_of_a_server_started_again_with_a_new_token_says_to_open_the_new_address(browser: Browser) -> None:
    with socket.socket() as probe:  # a free port, for both servers: the page comes back to the same address
        probe.bind(("127.0.0.1", 0))
        listen = f"127.0.0.1:{probe.getsockname()[1]}"
    environment = {k: v for k, v in os.environ.items() if k not in ("ICS35_PORT", "ICS35_WEB_TOKEN")}

    def start() -> tuple[subprocess.Popen[str], str]:
        proc = subprocess.Popen(
            [*WEB, "--listen", listen], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, env=environment
        )
        assert proc.stdout is not None
        return proc, proc.stdout.readline().strip()

    first, url = start()
    context = browser.new_context()
    p = context.new_page()
    p.goto(url)
    expect(p.locator("#line-status")).to_contain_text("115200 baud")
    first.terminate()
    first.wait(10)
    expect(p.locator("#line-status")).to_have_text("server gone")
    second, _ = start()  # every start makes a new token (none given): this page's is the old one
    try:
        # Not "server gone" while it runs: the page cannot use it, and says what to open instead.
        expect(p.locator("#message")).to_contain_text("another token")
        expect(p.locator("#line-status")).to_have_text("server started again: open its new address")
    finally:
        context.close()
        for proc in (first, second):
            proc.terminate()
            proc.wait(10)
            assert proc.stdout is not None
            proc.stdout.close()


def test_without_the_token_the_page_is_refused(browser: Browser, server: str) -> None:
    context = browser.new_context()
    refused = context.new_page().goto(base_of(server) + "/")
    assert refused is not None and refused.status == 401
    assert "no token" in refused.text()
    wrong = context.new_page().goto(base_of(server) + "/?token=not-the-token-at-all")
    assert wrong is not None and wrong.status == 403
    context.close()


def test_the_token_url_lands_on_the_line_page_without_the_token_in_the_address_bar(page: Page, server: str) -> None:
    assert "token" not in page.url
    expect(page.locator("#line-status")).to_contain_text("115200 baud")
    expect(page.locator("#sim-banner")).to_be_hidden()  # a pty port: real as far as the page knows


def test_scan_lists_the_servos_with_protocol_live_temperature_and_position(page: Page, lines: Any) -> None:
    sim = lines[0].sim
    sim.servo(3).command_position(8100)  # holding: the page's reads must leave it so
    page.click("a[href='#line']")
    scan_finds(page, 2)
    expect(page.locator("#scan-progress")).to_have_js_property("value", 32)  # every ID, as it went
    ics36, ics35 = page.locator("#servo-table tr[data-id='3']"), page.locator("#servo-table tr[data-id='1']")
    expect(ics36.locator("td.temp")).to_contain_text("°C")
    expect(ics36.locator("td.ics")).to_have_text("3.6")
    expect(ics36.locator("td.position")).to_have_text(re.compile(r"^\d+$"))
    expect(ics35.locator("td.ics")).to_have_text("3.5")
    expect(ics35.locator("td.position")).to_have_text("not read")
    page.wait_for_timeout(1200)  # another round of reads
    assert sim.servo(3).target == 8100 and sim.servo(1).free  # nothing moved, nothing went limp
    sim.servo(3).command_position(0)  # free again, as the later tests expect
    shot(page, "line")


def open_servo(p: Page, sid: int, *, speed: int) -> None:
    """``p`` on the Servo page of servo ``sid`` (whose EEPROM's speed is ``speed``), its EEPROM read (so a
    test runs alone too, not only after the tests before it in this module)."""
    p.click("a[href='#servo']")
    p.fill("#servo-id", str(sid))
    p.click("#servo-load")
    servo_read(p, sid)
    expect(p.locator("#eeprom-table [name=speed]")).to_have_value(str(speed))


def servo_read(p: Page, sid: int) -> None:
    """Wait until ``p``'s Servo page says it has read servo ``sid`` (its reads done: its buttons act on it).  (Its
    tables fill before the last read, and could be the page's last visit's.)"""
    expect(p.locator(f"#page-servo[data-loaded='{sid}']")).to_be_attached()


def test_a_field_is_changed_written_and_verified_on_the_servo(page: Page, lines: Any) -> None:
    sim = lines[0].sim
    page.click("a[href='#line']")
    if not page.locator("#servo-table tr[data-id='1'] a").is_visible():  # (this test run alone)
        scan_finds(page, 2)
    page.click("#servo-table tr[data-id='1'] a")
    field = page.locator("#eeprom-table [name=speed]")
    expect(field).to_have_value(str(sim.servo(1).eeprom.speed))
    field.fill("500")
    page.click("#plan-btn")
    expect(page.locator("#message")).to_have_text("speed must be in 1..127, got 500")  # words, nothing sent
    field.fill("77")
    page.click("#plan-btn")
    expect(page.locator("#diff tr.changed")).to_contain_text("77")
    expect(page.locator("#message")).to_be_hidden()  # the last try's error goes with the next try
    assert sim.servo(1).eeprom.speed != 77  # the diff is shown, nothing written yet
    shot(page, "servo", height=1660)
    page.click("#write-btn")
    expect(page.locator("#write-result")).to_contain_text("verified")
    assert sim.servo(1).eeprom.speed == 77


def test_backup_then_restore_from_the_file(page: Page, lines: Any, tmp_path: Path) -> None:
    sim = lines[0].sim
    speed = sim.servo(1).eeprom.speed
    open_servo(page, 1, speed=speed)
    backup = backed_up(page, tmp_path)
    assert backup.name == "servo-01.json" and f'"speed": {speed}' in backup.read_text()
    other = 20 if speed != 20 else 21
    page.locator("#eeprom-table [name=speed]").fill(str(other))
    page.click("#plan-btn")
    page.click("#write-btn")
    expect(page.locator("#write-result")).to_contain_text("verified")
    assert sim.servo(1).eeprom.speed == other
    page.set_input_files("#restore-file", str(backup))
    expect(page.locator("#restore-diff")).to_contain_text("speed")
    page.click("#restore-btn")
    expect(page.locator("#restore-result")).to_contain_text("verified")
    assert sim.servo(1).eeprom.speed == speed


def until(condition: Callable[[], bool], failure: str) -> None:
    """Wait for what the simulated line shows (only against a hang: GUARD)."""
    deadline = time.monotonic() + GUARD
    while not condition():
        assert time.monotonic() < deadline, failure
        time.sleep(0.01)


def test_jog_moves_the_servo_only_with_motion_enabled(page: Page, lines: Any) -> None:
    sim = lines[0].sim
    open_servo(page, 1, speed=sim.servo(1).eeprom.speed)
    expect(page.locator("#jog-plus")).to_be_disabled()
    sim.servo(1).move_by_hand(8200)
    page.check("#motion-switch")
    expect(page.locator("#jog-plus")).to_be_enabled()
    expect(page.locator("#jog-target")).to_have_text("8200")  # held where it stands
    assert sim.servo(1).target == 8200
    page.click("#jog-plus")
    expect(page.locator("#jog-target")).to_have_text("8300")  # shown at the click, before the command goes
    until(lambda: sim.servo(1).target == 8300, "the jog's command never reached servo 1")
    page.click("#free-btn")
    expect(page.locator("#jog-plus")).to_be_disabled()
    expect(page.locator("#message")).to_contain_text("free")


def test_renumbering_is_refused_in_words_with_two_servos_and_done_with_one(page: Page, lines: Any) -> None:
    two, lone = lines
    page.click("a[href='#id']")
    page.click("#survey-btn")
    expect(page.locator("#survey-result")).to_contain_text("not safe to renumber")
    page.fill("#new-id", "9")
    page.click("#renumber-btn")
    expect(page.locator("#id-result")).to_contain_text("exactly one device", timeout=SCAN_WAIT_MS)
    assert sorted(s.servo_id for s in two.sim.servos) == [1, 3]
    shot(page, "id")
    page.click("a[href='#line']")
    page.fill("#port-input", lone.path)
    page.click("#connect-btn")
    expect(page.locator("#message")).to_have_text(f"connected to {lone.path}")  # the answer, not a pushed status
    page.click("a[href='#id']")
    page.click("#renumber-btn")
    expect(page.locator("#id-result")).to_contain_text("ID 4 is now ID 9", timeout=SCAN_WAIT_MS)
    assert [s.servo_id for s in lone.sim.servos] == [9]
    page.click("a[href='#line']")
    page.fill("#port-input", two.path)
    page.click("#connect-btn")
    expect(page.locator("#message")).to_have_text(f"connected to {two.path}")


def test_a_port_that_cannot_be_opened_leaves_the_port_box_naming_the_line_still_open(browser: Browser) -> None:
    # A mistyped port was refused and the line stayed on the old one, but the box kept the refused name: a Scan
    # right after scanned the old line while the box named another.
    line = PtyLine((1,))
    with web_server_page(browser, line) as p:
        expect(p.locator("#port-input")).to_have_value(line.path)
        p.fill("#port-input", "/dev/ttyNOPE")
        p.click("#connect-btn")
        expect(p.locator("#message")).to_contain_text("/dev/ttyNOPE")
        expect(p.locator("#port-input")).to_have_value(line.path)
        expect(p.locator("#line-status")).to_contain_text(line.path)
        scan_finds(p, 1, ids="0-2")


def test_a_profile_goes_to_many_servos_with_a_result_each(page: Page, lines: Any) -> None:
    sim = lines[0].sim
    page.click("a[href='#many']")
    page.fill("#many-ids", "1,3")
    page.check("[name=use-punch]")
    page.click("#many-apply")
    expect(page.locator("#message")).to_have_text("give punch a value, or untick it")  # not taken as 0
    page.fill("[name=value-punch]", "4")
    page.click("#many-apply")
    expect(page.locator("#many-results tbody tr")).to_have_count(2)
    expect(page.locator("#many-results tr[data-id='3']")).to_contain_text("verified")
    assert sim.servo(1).eeprom.punch == 4 and sim.servo(3).eeprom.punch == 4
    shot(page, "many")


def test_the_live_plot_follows_a_servo_turned_by_hand(page: Page, lines: Any) -> None:
    servo = lines[0].sim.servo(3)
    page.click("a[href='#live']")
    page.fill("#live-ids", "1,3")
    page.click("#live-start")
    expect(page.locator("#legend span[data-id='3']")).to_be_visible()  # the page's CSP allows no eval: DOM waits
    for position in (8000, 9000, 10000, 8500, 6000):
        servo.move_by_hand(position)
        expect(page.locator("#legend span[data-id='3']")).to_have_text(f"■ 3: {position}")
        page.wait_for_timeout(150)  # a visible step on the plot
    shot(page, "live")
    with page.expect_download() as download:
        page.click("#live-export")
    csv = Path(download.value.path()).read_text().splitlines()
    assert csv[0].startswith("t,cycle,pos_1,target_1,current_1,temp_1,pos_3,target_3")
    rows = [dict(zip(csv[0].split(","), line.split(","), strict=True)) for line in csv[1:]]
    assert [r["pos_3"] for r in rows if r["pos_3"]][-1] == "6000"  # a frame lacks an ID that missed its cycle
    assert rows[-1]["target_3"] == "-1" and rows[-1]["target_1"] == "0"  # watched (ICS 3.6), free (ICS 3.5)
    # Seconds since the first frame recorded (it was the server's monotonic clock: 63208.7, a spreadsheet's
    # plot starting hours in), rising with the cycles.
    times = [float(r["t"]) for r in rows]
    assert times[0] == 0.0 and times == sorted(times) and 0.5 < times[-1] < 60, times
    page.click("#live-stop")


def test_the_traffic_page_shows_the_transactions(page: Page) -> None:
    page.click("a[href='#traffic']")  # recording starts with the page, and goes on while away from it
    base = page.url.split("/#")[0]

    def newest() -> int:
        entries = page.request.get(f"{base}/api/traffic").json()["entries"]
        return int(entries[-1]["seq"]) if entries else 0

    def recorded() -> bool:  # the page's WebSocket message has arrived: a read of the line is kept
        before = newest()
        page.request.get(f"{base}/api/servo/1/ram")
        return newest() > before

    until(recorded, "visiting the Traffic page never started the recording")
    page.click("a[href='#servo']")
    page.fill("#servo-id", "1")  # (not the ID an earlier test left there: this test runs alone too)
    page.click("#servo-load")
    page.click("a[href='#traffic']")
    expect(page.locator("#traffic-table tbody tr").first).to_be_visible()
    page.fill("#traffic-filter", "read eeprom")
    expect(page.locator("#traffic-table tbody tr").first).to_contain_text("a1 00")
    page.fill("#traffic-filter", "")
    shot(page, "traffic")
    page.click("#traffic-pause")  # stops the recording on the server: what the line does now is not kept

    def unrecorded() -> bool:  # the WebSocket's message has arrived: a read of the line is no longer kept
        before = newest()
        page.request.get(f"{base}/api/servo/1/ram")
        return newest() == before

    until(unrecorded, "pausing never stopped the recording")
    last = newest()
    page.click("a[href='#servo']")
    with page.expect_response(lambda r: r.url.endswith("/ram")):  # its reads are done on the line
        page.click("#servo-load")
    assert page.request.get(f"{base}/api/traffic?since={last}").json()["entries"] == []
    page.click("a[href='#traffic']")
    page.click("#traffic-pause")


def png_width(png: bytes) -> int:
    return int.from_bytes(png[16:20], "big")  # the IHDR chunk: width, then height


def test_on_a_phone_every_page_fits_the_screen_width(browser: Browser, server: str) -> None:
    context = browser.new_context(viewport={"width": 390, "height": 844}, is_mobile=True)
    p = context.new_page()
    p.goto(server)
    scan_finds(p, 2, ids="0-4")
    for name in ("line", "servo/1", "id", "many", "live", "traffic"):
        p.goto(base_of(server) + f"/#{name}")
        if name == "servo/1":
            expect(p.locator("#eeprom-table tbody tr").first).to_be_visible()
            shot(p, "phone", height=844, width=390)
        width = png_width(p.screenshot(full_page=True))
        assert width == 390, f"the {name} page is {width} px wide on a 390 px screen: it scrolls sideways"
    context.close()


def test_an_unplugged_port_is_shown_at_once_and_the_line_comes_back(page: Page, lines: Any) -> None:
    two = lines[0]
    page.click("a[href='#line']")
    expect(page.locator("#lost-banner")).to_be_hidden()
    two.sim.unplug()
    expect(page.locator("#lost-banner")).to_be_visible()
    expect(page.locator("#line-status")).to_contain_text("LOST")
    two.sim.replug()
    expect(page.locator("#lost-banner")).to_be_hidden()
    scan_finds(page, 2, ids="0-4")
    expect(page.locator("#scan-progress")).to_have_js_property("value", 5)  # the five IDs typed, no more


def test_a_message_that_the_port_is_lost_goes_when_the_line_is_back(page: Page, lines: Any) -> None:
    two = lines[0]
    page.click("a[href='#line']")
    two.sim.unplug()
    expect(page.locator("#lost-banner")).to_be_visible()
    page.click("#scan-btn")
    expect(page.locator("#message")).to_contain_text("lost")
    expect(page.locator("#scan-summary")).not_to_contain_text("scanning")  # the failed scan is not still going
    two.sim.replug()
    expect(page.locator("#lost-banner")).to_be_hidden()
    # The banner and the message follow the same status update: no wait beyond the one for the banner.
    expect(page.locator("#message")).not_to_contain_text("lost", timeout=500)
    expect(page.locator("#message")).to_contain_text("the line is back", timeout=500)
    scan_finds(page, 2, ids="0-4")


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


def test_the_servo_page_reports_the_position_read_after_a_jog_not_the_one_before(page: Page, lines: Any) -> None:
    servo = lines[0].sim.servo(3)  # ICS 3.6: its position is read without moving or freeing it
    servo.move_by_hand(8000)
    open_servo_page(page, 3)
    page.check("#motion-switch")
    expect(page.locator("#jog-target")).to_have_text("8000")
    for target in (8100, 8200):
        page.click("#jog-plus")
        expect(page.locator("#jog-target")).to_have_text(str(target))
    until(lambda: servo.target == 8200, "the jogs never reached servo 3")
    # There at once: the simulator's clock runs on the line's traffic (a few counts a read), not the wall's.
    servo.move_by_hand(8200)
    expect(page.locator("#jog-position")).to_have_text("8200")  # where the servo got to, not where it set off from
    expect(page.locator("#jog-position-note")).to_contain_text("read")
    assert servo.target == 8200  # the reads moved nothing
    page.click("#free-btn")
    expect(page.locator("#jog-plus")).to_be_disabled()
    servo.move_by_hand(9100)  # turned by hand while the page is open: the page follows
    expect(page.locator("#jog-position")).to_have_text("9100")
    assert servo.free  # the reads took no hold of it


def test_for_an_ics35_servo_the_servo_page_says_what_its_reported_position_is(page: Page, lines: Any) -> None:
    servo = lines[0].sim.servo(1)  # ICS 3.5: reads a position only by going free, so none is read
    servo.move_by_hand(7600)
    open_servo_page(page, 1)
    page.check("#motion-switch")
    expect(page.locator("#jog-target")).to_have_text("7600")
    page.click("#jog-plus")
    expect(page.locator("#jog-target")).to_have_text("7700")
    expect(page.locator("#jog-position-note")).to_contain_text("before")  # (the first read says so: not the jog)
    until(lambda: servo.target == 7700, "the jog's command never reached servo 1")
    page.wait_for_timeout(1200)  # several rounds of the page's reads
    assert servo.target == 7700  # held where it was sent: nothing freed it
    page.click("#free-btn")
    expect(page.locator("#jog-plus")).to_be_disabled()


@contextlib.contextmanager
def web_server_page(browser: Browser, line: PtyLine, args: list[str] | None = None) -> Iterator[Page]:
    """``ics35 web ARGS`` (by default ``--port`` ``line``'s pty) in a process of its own and a page on it; at the
    end the server is stopped and ``line`` closed, and the server must have printed no traceback."""
    proc = subprocess.Popen(
        [*WEB, *(["--port", line.path] if args is None else args), *PATIENT_OPTION],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "ICS35_WEB_TOKEN": ""},
    )
    assert proc.stdout is not None and proc.stderr is not None
    context = browser.new_context()
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


def test_a_servo_at_another_rate_is_named_and_the_page_reopens_the_line_at_its_rate(browser: Browser) -> None:
    line = PtyLine((1,))
    line.sim.add_device(VirtualServo(5, baud_rate=1250000))
    with web_server_page(browser, line) as p:
        expect(p.locator("#line-status")).to_contain_text("at 115200 baud")
        p.goto(p.url.split("#")[0] + "#servo/5")
        expect(p.locator("#message")).to_contain_text("ID 5 answers at 1,250,000 baud; reopen the line at that rate")
        p.get_by_role("button", name="Reopen the line at 1,250,000 baud").click()
        expect(p.locator("#line-status")).to_contain_text("at 1250000 baud")
        expect(p.locator("#eeprom-table [name=servo_id]")).to_have_value("5")
        expect(p.locator("#message")).to_have_text("the line is open at 1,250,000 baud")


def test_a_scan_whose_port_is_lost_part_way_lists_the_servos_it_found_and_says_the_loss(browser: Browser) -> None:
    line = PtyLine((1, 2))
    puller = UnplugsWhenAsked(3, ReadEeprom)
    line.sim.add_device(puller)
    with web_server_page(browser, line) as p:
        puller.line = line.sim
        p.fill("#scan-ids", "0-4")
        p.click("#scan-btn")
        expect(p.locator("#scan-summary")).to_contain_text(
            "3 servo(s) found before the line was lost", timeout=SCAN_WAIT_MS
        )
        expect(p.locator("#servo-table tbody tr")).to_have_count(3)
        expect(p.locator("#message")).to_contain_text("lost")
        expect(p.locator("#lost-banner")).to_be_visible()
        puller.line = None
        line.sim.replug()
        expect(p.locator("#message")).to_contain_text("the line is back")
        scan_finds(p, 3, ids="0-4")


def test_a_scan_that_finds_nothing_at_the_lines_rate_offers_the_rate_a_device_answers_at(browser: Browser) -> None:
    # Servos set to 1.25 Mbit/s, the page opened at the default 115200: it said "0 servo(s) found" and no more.
    line = PtyLine(())
    for i in (1, 2):
        line.sim.add_device(VirtualServo(i, baud_rate=1250000))
    with web_server_page(browser, line) as p:
        p.fill("#scan-ids", "0-4")
        p.click("#scan-btn")
        expect(p.locator("#message")).to_contain_text(
            "no servo answered at 115,200 baud, but a device does at 1,250,000 baud", timeout=SCAN_WAIT_MS
        )
        p.get_by_role("button", name="Reopen the line at 1,250,000 baud").click()
        expect(p.locator("#line-status")).to_contain_text("at 1250000 baud")
        scan_lists(p, 2)  # (scanned again at once)


def test_a_servo_given_another_id_on_its_page_is_read_again_at_that_id(browser: Browser) -> None:
    line = PtyLine((1,))
    with web_server_page(browser, line) as p:
        open_servo_page(p, 1)
        p.fill("#eeprom-table [name=servo_id]", "7")
        p.check("#allow-id-change")
        p.click("#plan-btn")
        expect(p.locator("#diff tr.changed")).to_contain_text("7")
        p.click("#write-btn")
        # The page follows the servo to its new ID: no read of the old one (no answer there, then a search
        # of the other rates) hiding the write's outcome behind a servo "not answering".
        expect(p.locator("#write-result")).to_contain_text("verified")
        expect(p.locator("#servo-id")).to_have_value("7")
        expect(p.locator("#eeprom-table [name=servo_id]")).to_have_value("7")
        expect(p.locator("#message")).to_have_text("servo 1 is now servo 7: written and verified")
        assert [s.servo_id for s in line.sim.servos] == [7]


def test_the_line_page_lists_a_renumbered_servo_at_its_new_id(browser: Browser) -> None:
    line = PtyLine((0, 2))
    with web_server_page(browser, line) as p:
        scan_finds(p, 2)
        open_servo_page(p, 2)
        p.fill("#eeprom-table [name=servo_id]", "3")
        p.check("#allow-id-change")
        p.click("#plan-btn")
        expect(p.locator("#diff tr.changed")).to_contain_text("3")
        p.click("#write-btn")
        expect(p.locator("#write-result")).to_contain_text("verified")
        aside = line.sim.remove_servo(3)  # a bag of new servos: renumbered one at a time on the ID page
        p.click("a[href='#id']")
        p.fill("#new-id", "5")
        p.click("#renumber-btn")
        expect(p.locator("#id-result")).to_contain_text("ID 0 is now ID 5", timeout=SCAN_WAIT_MS)
        line.sim.add_device(aside)
        p.click("a[href='#line']")
        # Listed at their IDs now, and read there: not the old IDs, which no longer answer.
        expect(p.locator("#servo-table tbody tr")).to_have_count(2)
        expect(p.locator("#servo-table tr[data-id='5'] td.temp")).to_contain_text("°C")
        expect(p.locator("#servo-table tr[data-id='3'] td.temp")).to_contain_text("°C")
        expect(p.locator("#servo-table tr[data-id='0']")).to_have_count(0)
        expect(p.locator("#servo-table tr[data-id='2']")).to_have_count(0)


def test_another_servos_page_keeps_neither_the_restore_file_nor_the_target(browser: Browser, tmp_path: Path) -> None:
    line = PtyLine((1, 2))
    with web_server_page(browser, line) as p:
        open_servo_page(p, 1)
        backup = backed_up(p, tmp_path)
        p.set_input_files("#restore-file", str(backup))
        expect(p.locator("#restore-diff")).to_contain_text("no change")
        p.check("#motion-switch")
        expect(p.locator("#jog-target")).to_have_text("7500")
        open_servo_page(p, 2)
        # Servo 1's file no longer shown as chosen beside a dead Restore button (choosing the same file
        # again is no change to a browser: it would do nothing), nor servo 1's target as servo 2's.
        expect(p.locator("#restore-file")).to_have_value("")
        expect(p.locator("#jog-target")).to_have_text("-")
        p.set_input_files("#restore-file", str(backup))
        expect(p.locator("#restore-diff")).to_contain_text("servo-01.json is a backup of ID 1; servo 2 keeps its ID")


def test_a_restore_file_that_is_not_a_backup_takes_the_last_files_diff_away(browser: Browser, tmp_path: Path) -> None:
    # The diff of the file chosen before stayed under the words refusing the new one, naming the old file as
    # if it were the one chosen (its Restore button disabled: nothing to press, but a diff of nothing chosen).
    line = PtyLine((1,))
    with web_server_page(browser, line) as p:
        open_servo_page(p, 1)
        backup = backed_up(p, tmp_path)
        p.set_input_files("#restore-file", str(backup))
        expect(p.locator("#restore-diff")).to_contain_text("no change")
        (tmp_path / "notes.json").write_text('{"hello": 1}')
        p.set_input_files("#restore-file", str(tmp_path / "notes.json"))
        expect(p.locator("#message")).to_contain_text("no 'format'")
        expect(p.locator("#restore-diff")).to_be_empty()
        p.set_input_files("#restore-file", str(backup))
        expect(p.locator("#restore-diff")).to_contain_text("no change")
        (tmp_path / "notes.txt").write_text("not json")
        p.set_input_files("#restore-file", str(tmp_path / "notes.txt"))
        expect(p.locator("#message")).to_contain_text("notes.txt: not JSON")
        expect(p.locator("#restore-diff")).to_be_empty()
        expect(p.locator("#restore-btn")).to_be_disabled()


def test_a_stopped_live_plot_no_longer_shows_the_streams_rate_as_now(browser: Browser) -> None:
    # Stop left "stream 99.8 cycles/s, page 26 updates/s" on show for good, as if it still ran.
    line = PtyLine((1,))
    with web_server_page(browser, line) as p:
        p.goto(p.url.split("#")[0] + "#live")
        p.fill("#live-ids", "1")
        p.click("#live-start")
        expect(p.locator("#live-updates")).to_have_text(re.compile(r"^[1-9]\d*$"))
        expect(p.locator("#live-rate")).to_have_text(re.compile(r"^\d"))
        p.click("#live-stop")
        expect(p.locator("#live-cycle")).to_contain_text("(stopped)")
        for part in ("#live-rate", "#live-updates", "#live-offline", "#live-watched", "#live-held"):
            expect(p.locator(part)).to_have_text("-")
        p.click("#live-start")  # started again: its figures come back
        expect(p.locator("#live-updates")).to_have_text(re.compile(r"^[1-9]\d*$"))
        expect(p.locator("#live-cycle")).not_to_contain_text("stopped")
        p.click("#live-stop")


def test_the_live_target_legend_says_free_and_left_alone_not_0_and_minus_1(browser: Browser) -> None:
    # The target plot's legend gave the stream's own marks as if they were positions: "1: 0" for a servo it
    # frees, "3: -1" for an ICS 3.6 servo it only reads; and the free servo's 0 was drawn, squashing the rest.
    line = PtyLine((1, 3), ics36=(3,))
    with web_server_page(browser, line) as p:
        p.goto(p.url.split("#")[0] + "#live")
        p.fill("#live-ids", "1,3")
        p.click("#live-start")
        expect(p.locator("#legend span[data-id='3']")).to_have_text("■ 3: 7500")
        p.select_option("#live-what", "targets")
        expect(p.locator("#legend span[data-id='1']")).to_have_text("■ 1: free")
        expect(p.locator("#legend span[data-id='3']")).to_have_text("■ 3: left alone")
        p.click("#live-stop")


def test_a_tick_allowing_an_id_or_baud_change_is_for_one_servos_write_not_the_next(browser: Browser) -> None:
    # Ticked for servo 1's write, "allow baud change" stayed ticked on servo 2's page and on servo 1's again after
    # the write: a restore of an old backup then changed the servo's rate with no tick of its own.
    line = PtyLine((1, 2))
    with web_server_page(browser, line) as p:
        open_servo_page(p, 1)
        ticks = ("#allow-id-change", "#allow-baud-change", "#restore-id")
        for tick in ticks:
            p.check(tick)
        open_servo_page(p, 2)
        for tick in ticks:
            expect(p.locator(tick)).not_to_be_checked()
        p.select_option("#eeprom-table [name=baud_rate]", "1250000")
        p.check("#allow-baud-change")
        p.click("#plan-btn")
        p.click("#write-btn")
        expect(p.locator("#write-result")).to_contain_text("verified")
        assert line.sim.servo(2).eeprom.baud_rate == 1250000
        expect(p.locator("#allow-baud-change")).not_to_be_checked()  # (written: the next change needs its own)


def test_a_write_refused_for_its_id_or_baud_change_names_the_tick_that_allows_it(browser: Browser) -> None:
    # "refused: servo 1: the write changes its ID to 7", and nothing said the tick below the table allows it.
    line = PtyLine((1,))
    with web_server_page(browser, line) as p:
        open_servo_page(p, 1)
        p.fill("#eeprom-table [name=servo_id]", "7")
        p.click("#plan-btn")
        expect(p.locator("#diff .refusal")).to_contain_text("the write changes its ID to 7")
        expect(p.locator("#diff")).to_contain_text("tick “allow ID change” to write it")
        p.fill("#eeprom-table [name=servo_id]", "1")
        p.select_option("#eeprom-table [name=baud_rate]", "1250000")
        p.click("#plan-btn")
        expect(p.locator("#diff")).to_contain_text("tick “allow baud change” to write it")
        p.check("#allow-baud-change")
        p.click("#plan-btn")
        expect(p.locator("#diff tr.changed")).to_contain_text("1250000")
        expect(p.locator("#diff")).not_to_contain_text("tick")
        expect(p.locator("#write-btn")).to_be_enabled()


def test_a_listed_servo_that_stops_answering_is_told_in_words_not_with_its_last_values(browser: Browser) -> None:
    line = PtyLine((1, 2))
    with web_server_page(browser, line) as p:
        scan_finds(p, 2)
        row = p.locator("#servo-table tr[data-id='2']")
        expect(row.locator("td.temp")).to_contain_text("°C")
        line.sim.remove_servo(2)  # its cable pulled
        # Not the library's words with the raw bytes sent, beside the last current read as if read now.
        expect(row.locator("td.temp")).to_have_text("not answering (open it to see why)")
        expect(row.locator("td.current")).to_have_text("-")
        expect(row.locator("td.temp")).to_have_attribute("title", re.compile("no reply"))


def test_a_servo_found_at_another_rate_is_listed_as_not_read_at_this_one(browser: Browser) -> None:
    line = PtyLine((1,))
    line.sim.add_device(VirtualServo(5, baud_rate=1250000))
    with web_server_page(browser, line) as p:
        p.check("#scan-all-bauds")
        scan_finds(p, 2)
        expect(p.locator("#servo-table tr[data-id='1'] td.temp")).to_contain_text("°C")
        # Its reads wait for nothing: the line reads only the servos at its own rate (it showed "…" for ever).
        expect(p.locator("#servo-table tr[data-id='5'] td.temp")).to_have_text(
            "not read: the line is at 115200 baud (Connect at 1250000 to read it)"
        )
        # Many servos and Live plots start from the servos found at the line's rate: servo 5 pre-filled there
        # failed with "no reply" (Many) or was plotted offline (Live).
        p.click("a[href='#many']")
        expect(p.locator("#many-ids")).to_have_value("1")
        p.click("a[href='#live']")
        p.click("#live-start")
        expect(p.locator("#legend span[data-id='1']")).to_be_visible()
        expect(p.locator("#legend span[data-id='5']")).to_have_count(0)
        p.click("#live-stop")


@contextlib.contextmanager
def held_by_its_page(browser: Browser, position: int) -> Iterator[tuple[PtyLine, VirtualServo, Page]]:
    """Servo 1 alone on a line, turned by hand to ``position``, its page open with motion switched on (so held
    there): the line, the servo and the page."""
    line = PtyLine((1,))
    servo = line.sim.servo(1)
    servo.move_by_hand(position)
    with web_server_page(browser, line) as p:
        open_servo_page(p, 1)
        p.check("#motion-switch")
        expect(p.locator("#jog-target")).to_have_text(str(position))
        yield line, servo, p


def test_motion_switched_on_before_the_line_was_lost_must_be_switched_on_again(browser: Browser) -> None:
    with held_by_its_page(browser, 8000) as (line, servo, p):
        until(lambda: servo.target == 8000, "enable motion never held servo 1")
        line.sim.unplug()
        expect(p.locator("#lost-banner")).to_be_visible()
        line.sim.power_cycle(1)  # the servos' supply went too: it restarted, free, and was turned by hand
        line.sim.move_by_hand(1, 6000)
        line.sim.replug()
        expect(p.locator("#lost-banner")).to_be_hidden()
        # A jog from the old target would throw it from 6000 to 8100: motion is off until switched on again.
        expect(p.locator("#motion-switch")).not_to_be_checked()
        expect(p.locator("#jog-plus")).to_be_disabled()
        refused = p.request.post(p.url.split("#")[0] + "api/servo/1/move", data={"position": 8100})
        assert refused.status == 409 and "switch on" in refused.json()["error"], refused.text()
        assert servo.free and servo.position == 6000
        p.check("#motion-switch")  # switched on again: held where it stands now
        expect(p.locator("#jog-target")).to_have_text("6000")


def test_a_refused_jog_leaves_the_target_at_the_last_one_sent(browser: Browser) -> None:
    # The page shows a jog's target at the click.  The server refusing it (409: motion switched off meanwhile,
    # nothing sent) must not leave the page showing a target the servo never got.
    with held_by_its_page(browser, 8000) as (_, servo, p):
        held: list[Route] = []
        p.route("**/api/servo/1/move", lambda route: held.append(route))  # the request waits here until continued
        p.click("#jog-plus")
        expect(p.locator("#jog-target")).to_have_text("8100")  # (shown at the click)
        deadline = time.monotonic() + GUARD
        while not held:
            assert time.monotonic() < deadline, "the jog was never asked"
            p.wait_for_timeout(20)
        off = p.request.post(p.url.split("#")[0] + "api/servo/1/motion", data={"enabled": False})
        assert off.status == 200, off.text()
        held[0].continue_()
        expect(p.locator("#message")).to_contain_text("motion is not enabled for servo 1")
        expect(p.locator("#jog-target")).to_have_text("8000")  # the last target sent, not the refused one
        expect(p.locator("#jog-slider")).to_have_value("8000")
        assert servo.target == 8000
        p.unroute("**/api/servo/1/move")


def test_a_jog_whose_answer_was_lost_shows_its_target_as_uncertain(browser: Browser) -> None:
    # A servo that did not answer the jog (504) may have heard it: its target is the new one or the old.
    with held_by_its_page(browser, 8000) as (line, _, p):
        line.sim.remove_servo(1)  # its cable pulled: the jog goes out, no answer comes back
        with p.expect_response("**/api/servo/1/move") as answer:
            p.click("#jog-plus")
        assert answer.value.status == 504, answer.value.text()
        expect(p.locator("#jog-target")).to_have_text("8100? (not confirmed)")
        expect(p.locator("#jog-target")).to_have_attribute("title", re.compile("may"))


# How soon the server switches off the motion of a page that is gone: at once for a tab closed (its socket
# closes), a few seconds for one whose network went (no answer to the server's pings).
PAGE_GONE_BOUND = scaled(8.0)


def test_motion_a_closed_tab_switched_on_goes_off_on_the_server_and_a_jog_is_refused(browser: Browser) -> None:
    line = PtyLine((1,))
    servo = line.sim.servo(1)
    servo.move_by_hand(8000)
    with web_server_page(browser, line) as p:
        open_servo_page(p, 1)
        p.check("#motion-switch")
        until(lambda: servo.target == 8000, "enable motion never held servo 1")
        base, api = p.url.split("#")[0], p.context.request  # (the tab's cookie, without the tab)
        assert api.get(base + "api/status").json()["motion_on"] == [1]
        p.close()  # the tab closed, its switch on: no page is left to say motion is on
        deadline = time.monotonic() + PAGE_GONE_BOUND
        while api.get(base + "api/status").json()["motion_on"]:
            assert time.monotonic() < deadline, "motion stayed on after the page that switched it on was closed"
            time.sleep(0.05)
        refused = api.post(base + "api/servo/1/move", data={"position": 8100})
        assert refused.status == 409 and "page" in refused.json()["error"], refused.text()
        assert servo.target == 8000 and not servo.free  # nothing sent; it keeps holding, as when the page is left


def motion_switched_off_by_a_lost_port(p: Page, line: PtyLine) -> None:
    """Servo 1's page with its motion switched on, then the port lost and back: the server switched it off."""
    servo = line.sim.servo(1)
    open_servo_page(p, 1)
    p.check("#motion-switch")
    until(lambda: not servo.free, "enable motion never held servo 1")
    line.sim.unplug()
    expect(p.locator("#lost-banner")).to_be_visible()
    line.sim.replug()
    expect(p.locator("#lost-banner")).to_be_hidden()
    expect(p.locator("#motion-switch")).not_to_be_checked()  # (motion off: the port was lost)


def test_a_status_pushed_while_enable_motion_is_asked_leaves_the_switch_ticked(browser: Browser) -> None:
    # The page unticks a switch whose motion the server switched off (here: a lost port).  A status pushed
    # between the tick and the server's answer still says so: it unticked the switch, and the server then
    # switched motion on behind a page showing it off.
    line = PtyLine((1, 3))
    with web_server_page(browser, line) as p:
        motion_switched_off_by_a_lost_port(p, line)
        held: list[Route] = []
        p.route("**/api/servo/1/motion", lambda route: held.append(route))  # the request waits here until continued
        p.click("#motion-switch")
        until(lambda: len(held) == 1, "enable motion was never asked")
        # Another change on the server (servo 3's motion switched on elsewhere): a status is pushed.
        other = p.request.post(p.url.split("#")[0] + "api/servo/3/motion", data={"enabled": True})
        assert other.status == 200, other.text()
        time.sleep(0.5)  # (the push reaches the page)
        expect(p.locator("#motion-switch")).to_be_checked()
        expect(p.locator("#jog-plus")).to_be_disabled()  # not on before the server says so
        held[0].continue_()
        expect(p.locator("#jog-plus")).to_be_enabled()
        expect(p.locator("#motion-switch")).to_be_checked()
        p.unroute("**/api/servo/1/motion")


def test_a_status_from_before_the_servers_answer_to_enable_motion_leaves_the_switch_ticked(browser: Browser) -> None:
    # The status the server pushes and its answer to the tick travel apart: one sent just before the tick was
    # taken (saying motion is off) can reach the page after the answer.  It unticked the switch of a servo
    # whose motion the server had just switched on.
    line = PtyLine((1, 3))
    with web_server_page(browser, line) as p:
        holding, late = [False], []

        def relay(ws: Any) -> None:  # the page's WebSocket through this test: its pushes held back when asked
            server = ws.connect_to_server()
            server.on_message(lambda m: late.append((ws, m)) if holding[0] else ws.send(m))
            ws.on_message(server.send)

        p.route_web_socket(re.compile(r"/ws(\?|$)"), relay)  # (the page names itself: /ws?page=...)
        p.reload()
        motion_switched_off_by_a_lost_port(p, line)
        holding[0] = True
        other = p.request.post(p.url.split("#")[0] + "api/servo/3/motion", data={"enabled": True})
        assert other.status == 200, other.text()
        deadline = time.monotonic() + GUARD
        while not late:  # a status pushed (it says motion is off for servo 1)
            assert time.monotonic() < deadline, "no status was pushed"
            p.wait_for_timeout(20)  # (Playwright relays the WebSocket only while the test waits on it)
        p.check("#motion-switch")
        expect(p.locator("#jog-plus")).to_be_enabled()  # the server's answer: on
        holding[0] = False
        for ws, message in late:
            ws.send(message)
        p.wait_for_timeout(300)
        expect(p.locator("#motion-switch")).to_be_checked()
        expect(p.locator("#jog-plus")).to_be_enabled()


@dataclass
class RobotServer:
    """``ics35 web --robot`` running: its URL, its process and the file its stderr goes to."""

    url: str
    proc: subprocess.Popen[str]
    stderr: Path

    def stacks(self) -> str:
        """What the server's threads are doing (faulthandler on SIGUSR1), and everything it wrote to stderr."""
        self.proc.send_signal(signal.SIGUSR1)
        time.sleep(1.0)
        return self.stderr.read_text(errors="replace")


# Its start: the CLI as a user runs it, with faulthandler's thread dump on SIGUSR1 (for a test's failure).
ROBOT_WEB = DUMP_ON_USR1 + "import sys; from ics35_async.cli import main; sys.argv[0] = 'ics35'; sys.exit(main())"


# The robot's server streams its 17 joints for as long as it runs: its tests come last, so it is started
# after the other pages' tests and stopped with the module.
@pytest.fixture(scope="module")
def robot_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[RobotServer]:
    """``ics35 web --robot``: the 17-joint humanoid of ``examples/humanoid.toml`` on two simulated lines,
    cycling at 50 Hz instead of 100 (half the transactions its simulators serve while it runs; nothing the
    pages show depends on the rate), with two retries for the pages' reads: the file has none, and on a
    loaded machine a real-time simulator's echo once came after the allowance (the Servo page then says so
    and waits for the user's Read)."""
    example = (ROOT / "examples" / "humanoid.toml").read_text()
    assert example.count("rate_hz = 100") == 2 and "retries" not in example
    folder = tmp_path_factory.mktemp("robot")
    robot = folder / "humanoid.toml"
    robot.write_text(example.replace("rate_hz = 100", "rate_hz = 50\nretries = 2"))
    stderr = folder / "server.stderr"
    with stderr.open("w") as err:
        proc = subprocess.Popen(
            [sys.executable, "-c", ROBOT_WEB, "web", "--no-browser", "--robot", str(robot)],
            stdout=subprocess.PIPE,
            stderr=err,
            text=True,
        )
    assert proc.stdout is not None
    yield RobotServer(proc.stdout.readline().strip(), proc, stderr)
    proc.terminate()
    proc.wait(10)
    proc.stdout.close()


@contextlib.contextmanager
def explained(p: Page, server: RobotServer) -> Iterator[None]:
    """A failure inside says which of the page's requests never finished and what the server's threads
    were doing (a page waiting on an answer that never comes shows only its own empty boxes)."""
    started = time.monotonic()
    pending: dict[Request, str] = {}
    ended: list[str] = []

    def begin(r: Request) -> None:
        pending[r] = f"{time.monotonic() - started:.2f}s {r.method} {r.url.split('?')[0]}"

    def end(r: Request, how: str) -> None:
        text = pending.pop(r, f"? {r.method} {r.url}")
        ended.append(f"{text} -> {how} at {time.monotonic() - started:.2f}s")

    p.on("request", begin)
    p.on("requestfinished", lambda r: end(r, "finished"))
    p.on("requestfailed", lambda r: end(r, f"failed ({r.failure})"))
    try:
        yield
    except AssertionError as exc:
        raise AssertionError(
            f"{exc}\n--- the page's requests never finished: {list(pending.values())}\n"
            f"--- the last ones finished: {ended[-12:]}\n--- the server:\n{server.stacks()}"
        ) from exc


def test_the_robot_page_moves_a_joint_and_plays_a_motion(browser: Browser, robot_server: RobotServer) -> None:
    context = browser.new_context(viewport={"width": 1280, "height": 1000})
    p = context.new_page()
    with explained(p, robot_server):
        p.goto(robot_server.url)
        p.click("#robot-link")
        expect(p.locator("#robot-table tbody tr")).to_have_count(17)
        elbow = p.locator("tr[data-joint='right_elbow']")
        expect(elbow.locator("input[type=range]")).to_be_disabled()
        p.check("#robot-motion")
        expect(elbow.locator("input[type=range]")).to_be_enabled()
        elbow.locator("input[type=range]").fill("60")  # a slider's change event
        expect(elbow.locator(".target")).to_have_text("60")
        expect(elbow.locator(".angle")).to_have_text(re.compile(r"^(59\.\d|60(\.\d)?)$"))  # the servo got there
        p.set_input_files("#robot-motion-file", str(ROOT / "examples/wave.json"))
        p.click("#robot-play")
        expect(p.locator("#robot-state")).to_contain_text("playing wave")
        p.wait_for_timeout(1500)  # mid-wave, for the picture
        shot(p, "robot")
        expect(p.locator("#robot-state")).to_contain_text("wave: done", timeout=30_000)
        expect(p.locator("#robot-state")).to_contain_text("all within limits")
    context.close()


def test_ticking_enable_motion_stays_ticked_while_the_server_has_not_answered(
    browser: Browser, robot_server: RobotServer
) -> None:
    # The robot's state comes pushed several times a second, saying motion is off until the server
    # has taken the tick: the box must not flip back meanwhile (a user would see it untick itself).
    context = browser.new_context()
    p = context.new_page()
    with explained(p, robot_server):
        p.goto(robot_server.url)
        p.click("#robot-link")
        box = p.locator("#robot-motion")
        # The first pushed state sets the box: before it, a test before this one that left motion on
        # would tick it under the click below (which would then untick it).
        expect(p.locator("#robot-cycle")).not_to_have_text("-")
        if box.is_checked():
            with p.expect_response("**/api/robot/motion"):
                p.uncheck("#robot-motion")
        held: list[Route] = []
        p.route("**/api/robot/motion", lambda route: held.append(route))  # the request waits here until continued
        p.click("#robot-motion")
        expect(box).to_be_checked()
        for _ in range(3):  # pushed states, each saying motion is still off
            cycle = p.locator("#robot-cycle").text_content() or ""
            expect(p.locator("#robot-cycle")).not_to_have_text(cycle)
            expect(box).to_be_checked()
        assert len(held) == 1
        assert held[0].request.post_data_json["enabled"] is True
        held[0].continue_()
        elbow = p.locator("tr[data-joint='right_elbow'] input[type=range]")
        expect(elbow).to_be_enabled()  # the server's answer: motion on
        p.unroute("**/api/robot/motion")
        p.uncheck("#robot-motion")  # as the other robot tests expect to find it
        expect(elbow).to_be_disabled()
    context.close()


def test_the_robots_motion_goes_off_with_the_page_that_switched_it_on_and_the_other_tabs_follow(
    browser: Browser, robot_server: RobotServer, tmp_path: Path
) -> None:
    # A tab closed with "enable motion" on left the robot armed on the server: any later tab or script
    # could move a standing robot.  The motion playing stops smoothly, as when the switch is turned off.
    slow = tmp_path / "slow.json"  # (long enough to be still playing when the tab closes, however slow the machine)
    slow.write_text('{"format": "ics35-motion", "version": 1, "name": "slow turn",'
                    ' "keyframes": [{"time": 30.0, "pose": {"head_yaw": 30}}]}')  # fmt: skip
    context = browser.new_context()
    p, other = context.new_page(), context.new_page()
    with explained(other, robot_server):
        base, api = robot_server.url.split("?")[0], context.request
        motion_on = lambda: api.get(base + "api/robot").json()["motion_enabled"]  # noqa: E731
        for tab in (p, other):
            tab.goto(robot_server.url)
            tab.click("#robot-link")
            expect(tab.locator("#robot-cycle")).not_to_have_text("-")  # its first pushed state came
        expect(p.locator("#robot-motion")).not_to_be_checked()
        p.check("#robot-motion")
        expect(other.locator("#robot-motion")).to_be_checked()  # a page follows the server's state
        p.set_input_files("#robot-motion-file", str(slow))
        p.click("#robot-play")
        expect(other.locator("#robot-state")).to_contain_text("playing slow turn")
        p.close()  # the tab that switched it on, closed with its switch on
        expect(other.locator("#robot-motion")).not_to_be_checked(timeout=int(PAGE_GONE_BOUND * 1000))
        said = "slow turn: stopped (motion switched off: the page that switched it on was closed or lost its"
        expect(other.locator("#robot-state")).to_contain_text(said)
        assert not motion_on()
        refused = api.post(base + "api/robot/move", data={"pose": {"right_elbow": 30}})
        assert refused.status == 409 and "enable motion" in refused.json()["error"], refused.text()
        # Reloaded, a page is another page: the one that switched motion on is gone.
        other.check("#robot-motion")
        expect(other.locator("tr[data-joint='right_elbow'] input[type=range]")).to_be_enabled()
        other.reload()
        until(lambda: not motion_on(), "motion stayed on after the page that switched it on was reloaded")
        expect(other.locator("#robot-cycle")).not_to_have_text("-")
        expect(other.locator("#robot-motion")).not_to_be_checked()
        expect(other.locator("#robot-state")).to_contain_text("motion switched off: the page that switched it on")
    context.close()


def test_with_a_robot_every_page_leads_to_every_other_and_its_servos_open_from_the_robot_page(
    browser: Browser, robot_server: RobotServer
) -> None:
    context = browser.new_context(viewport={"width": 1280, "height": 1000})
    p = context.new_page()
    with explained(p, robot_server):
        p.goto(robot_server.url)
        expect(p.locator("#line-status")).to_contain_text("the robot's line upper")  # no --port: the robot's line
        pages = ("line", "servo", "id", "many", "live", "traffic", "robot")
        for here in pages:
            p.click(f"nav a[href='#{here}']")
            expect(p.locator(f"#page-{here}")).to_be_visible()
            for there in pages:
                expect(p.locator(f"nav a[href='#{there}']")).to_be_visible()
        p.click("nav a[href='#line']")
        expect(p.locator("#robot-lines-table tbody tr")).to_have_count(2)
        p.click("#robot-lines-table tr[data-line='upper'] button")
        expect(p.locator("#line-status")).to_contain_text("the robot's line upper")
        scan_lists(p, 7)  # found on the robot's own line
        p.click("#servo-table tr[data-id='4'] a")
        expect(p.locator("#servo-robot-note")).to_contain_text("right_elbow")
        expect(p.locator("#eeprom-table [name=speed]")).to_be_visible()
        p.click("nav a[href='#robot']")
        p.click("tr[data-joint='right_knee'] a")  # a joint's servo, on the other line
        expect(p.locator("#page-servo")).to_be_visible()
        expect(p.locator("#line-status")).to_contain_text("the robot's line legs")
        expect(p.locator("#servo-robot-note")).to_contain_text("right_knee")
        expect(p.locator("#servo-id")).to_have_value("3")
        # The page has read the servo (a read still under way could end after the refusal and say its own words).
        expect(p.locator("#eeprom-table [name=speed]")).to_be_visible()
        expect(p.locator("#ram-table tbody tr").first).to_be_visible()  # its RAM read done too
        p.click("#free-btn")  # refused in words: the robot moves and frees its joints
        expect(p.locator("#message")).to_contain_text("Robot page")
        p.click("nav a[href='#robot']")
        p.click("#robot-line-links button[data-line='legs']")
        expect(p.locator("#page-line")).to_be_visible()
        scan_lists(p, 10)
    context.close()


def test_a_joint_freed_for_over_current_is_reset_on_the_robot_page_and_moves_again(
    browser: Browser, tmp_path: Path
) -> None:
    # A free servo draws no current, so a current trip of a joint the watch freed stands until the person says
    # its cause is dealt with: the joint's Reset button, and nothing else, lets it move again.
    line = PtyLine((1, 2))
    robot = tmp_path / "arm.toml"
    robot.write_text(
        f'[lines.arm]\nport = "{line.path}"\n[joints.shoulder]\nline = "arm"\nid = 1\n'
        '[joints.elbow]\nline = "arm"\nid = 2\nmin = -90\nmax = 90\n'
        '[safety]\nmax_current = 20\naction = "free"\n'
    )
    with web_server_page(browser, line, ["--robot", str(robot)]) as p:
        p.click("#robot-link")
        p.check("#robot-motion")
        expect(p.locator("#robot-state")).to_contain_text("joints hold where they stand")
        elbow = p.locator("tr[data-joint='elbow']")
        line.sim.servo(2).load = 40  # a load the elbow cannot carry
        expect(elbow.locator(".safety")).to_contain_text("draws current")
        until(lambda: line.sim.servo(2).free, "the watch did not free the elbow")
        expect(elbow.locator(".current")).to_have_text("0")  # read free: within the limits, still stopped
        expect(elbow.locator(".safety")).to_contain_text("draws current")
        line.sim.servo(2).load = 0
        elbow.get_by_role("button", name="Reset").click()
        expect(elbow.locator(".safety")).to_have_text("ok")
        expect(p.locator("#robot-state")).to_contain_text("joint elbow: safety stop reset")
        assert line.sim.servo(2).free  # reset moves nothing
        elbow.locator("input[type=range]").fill("30")
        expect(elbow.locator(".target")).to_have_text("30")
        until(lambda: not line.sim.servo(2).free, "the elbow was not moved again")


def test_the_robot_page_says_a_lost_line_and_reconnects_when_it_is_back(browser: Browser, tmp_path: Path) -> None:
    # The page said nothing and kept saying "open" after a line was lost; only a restart brought it back.
    # shoulder on an ICS 3.6 servo (read again at a reconnect), elbow on an ICS 3.5 one (asked about).
    line = PtyLine((1, 2), ics36=(1,))
    robot = tmp_path / "arm.toml"
    robot.write_text(
        f'[lines.arm]\nport = "{line.path}"\n[joints.shoulder]\nline = "arm"\nid = 1\n'
        '[joints.elbow]\nline = "arm"\nid = 2\n'
    )
    with web_server_page(browser, line, ["--robot", str(robot)]) as p:
        p.click("#robot-link")
        expect(p.locator("#robot-cycle")).not_to_have_text("-")
        expect(p.locator("#robot-reopen")).to_be_hidden()
        p.check("#robot-motion")  # the joints hold where they stand: elbow's servo holds a target
        expect(p.locator("#robot-state")).to_contain_text("joints hold where they stand")
        until(lambda: line.sim.servo(2).target is not None, "elbow's servo never got a target")
        elbow = line.sim.servo(2).target
        line.sim.unplug()
        expect(p.locator("#robot-error")).to_contain_text("lost")
        expect(p.locator("#robot-reopen-choice")).to_be_visible()  # elbow held a target: the page asks
        expect(p.locator("#robot-reopen-question")).to_contain_text("elbow held their targets")
        expect(p.locator("#robot-reopen")).to_be_hidden()
        expect(p.locator("#robot-motion")).to_be_disabled()
        line.sim.replug()
        p.click("#robot-reopen-hold")
        expect(p.locator("#robot-reopen-choice")).to_be_hidden()
        expect(p.locator("#robot-reopen")).to_be_hidden()
        expect(p.locator("#robot-error")).to_have_text("")
        assert line.sim.servo(2).target == elbow and not line.sim.servo(2).free  # never went limp
        line.sim.unplug()  # again, with motion off now: the same question, and the plain button stays hidden
        expect(p.locator("#robot-reopen-choice")).to_be_visible()
        line.sim.replug()
        p.click("#robot-reopen-free")
        expect(p.locator("#robot-reopen-choice")).to_be_hidden()
        until(lambda: line.sim.servo(2).free, "elbow's servo was not freed")
        expect(p.locator("#robot-error")).to_have_text("")
        expect(p.locator("#robot-motion")).to_be_enabled()
        p.check("#robot-motion")  # and the robot answers again: motion on, the joints held where they stand
        expect(p.locator("#robot-state")).to_contain_text("joints hold where they stand")


def test_the_live_plot_says_a_servo_held_after_a_lost_port_and_why(browser: Browser) -> None:
    # The stream sends a servo it held nothing once the port is back (it may have restarted, free and
    # elsewhere): plotted as if plain, its line just went flat; the terminal says "waiting for a target".
    line = PtyLine((1,))
    with web_server_page(browser, line) as p:
        p.goto(p.url.split("#")[0] + "#live")
        p.fill("#live-ids", "1")
        p.click("#live-start")
        expect(p.locator("#legend span[data-id='1']")).to_be_visible()
        expect(p.locator("#live-held")).to_have_text("none")
        answer = p.request.post(p.url.split("#")[0] + "api/servo/1/motion", data={"enabled": True})
        assert answer.ok and answer.json()["enabled"], answer.text()
        line.sim.unplug()
        expect(p.locator("#lost-banner")).to_be_visible()
        line.sim.replug()
        expect(p.locator("#lost-banner")).to_be_hidden()
        expect(p.locator("#live-held")).to_contain_text("1 (held: resumed")
        expect(p.locator("#legend span[data-id='1']")).to_contain_text("held: resumed")
        p.click("#live-stop")


def test_the_many_servos_page_says_one_failure_once_naming_its_servos_in_words(browser: Browser) -> None:
    # Each absent ID had a row of the library's words with the bytes sent ("read_eeprom to ID 5: no reply
    # ... (raw: a5 00)"), the same news once per servo.
    line = PtyLine((1,))
    with web_server_page(browser, line) as p:
        p.goto(p.url.split("#")[0] + "#many")
        p.fill("#many-ids", "1,5,6")
        p.check("[name=use-punch]")
        p.fill("[name=value-punch]", "3")
        p.click("#many-apply")
        expect(p.locator("#many-results tbody tr")).to_have_count(3)
        expect(p.locator("#many-results tr[data-id='1']")).to_contain_text("verified")
        expect(p.locator("#many-errors li")).to_have_count(1)
        expect(p.locator("#many-errors li")).to_contain_text(re.compile(r"^servos 5, 6: no reply at 115,200 baud"))
        expect(p.locator("#many-results tr[data-id='6']")).to_contain_text("failed (see above)")
        assert "raw" not in (p.locator("#page-many").text_content() or "")
        assert line.sim.servo(1).eeprom.punch == 3


def test_leaving_a_servos_page_switches_its_motion_off_on_the_server_too(browser: Browser) -> None:
    # The page unticked "enable motion" when it was left (or opened again), the server kept it on: a jog from
    # another tab moved a servo whose page said it was locked.
    line = PtyLine((1,))
    servo = line.sim.servo(1)
    with web_server_page(browser, line) as p:
        base = p.url.split("#")[0]

        def jog_refused() -> bool:
            answer = p.request.post(base + "api/servo/1/move", data={"position": 7600})
            return answer.status == 409 and "enable motion" in answer.json()["error"]

        open_servo_page(p, 1)
        p.check("#motion-switch")
        expect(p.locator("#jog-target")).to_have_text("7500")
        p.click("a[href='#line']")
        motion_on = lambda: p.request.get(base + "api/status").json()["motion_on"]  # noqa: E731
        until(lambda: motion_on() == [], "motion stayed on on the server after its page was left")
        assert jog_refused() and servo.target == 7500
        open_servo_page(p, 1)
        expect(p.locator("#motion-switch")).not_to_be_checked()
        p.check("#motion-switch")
        expect(p.locator("#jog-plus")).to_be_enabled()
        held = int(p.locator("#jog-target").text_content() or "")  # (where it stood: the free may read it off by one)
        other = p.context.new_page()  # the same servo's page in another tab: one page at a time jogs it
        other.goto(base + "#servo/1")
        expect(other.locator("#eeprom-table [name=servo_id]")).to_have_value("1")
        expect(p.locator("#motion-switch")).not_to_be_checked()
        expect(p.locator("#jog-plus")).to_be_disabled()
        assert jog_refused()
        assert servo.target == held
        other.close()


def test_the_live_plots_legend_says_a_servo_that_stopped_answering_is_offline(browser: Browser) -> None:
    # Its last position stayed in the legend as if read now ("■ 2: 7500"), the word only in the line above.
    line = PtyLine((1, 2))
    with web_server_page(browser, line) as p:
        p.goto(p.url.split("#")[0] + "#live")
        p.fill("#live-ids", "1,2")
        p.click("#live-start")
        expect(p.locator("#legend span[data-id='2']")).to_have_text("■ 2: 7500")
        unplugged = line.sim.remove_servo(2)
        expect(p.locator("#live-offline")).to_have_text("2")
        expect(p.locator("#legend span[data-id='2']")).to_have_text("■ 2: 7500 (offline)")
        line.sim.add_device(unplugged)
        expect(p.locator("#legend span[data-id='2']")).to_have_text("■ 2: 7500")
        p.click("#live-stop")


def test_motion_is_not_switched_on_for_a_servo_whose_read_failed_until_it_is_read(browser: Browser) -> None:
    # The page's read failed (the servo unplugged), the switch was ticked once it answered: motion went on for
    # a servo whose pulse limits the page had not read, and leaving the page left it on on the server.  The
    # page acts only on a servo it has read: the switch is refused until Read succeeds.
    line = PtyLine((1,))
    unplugged = line.sim.remove_servo(1)
    with web_server_page(browser, line) as p:
        base = p.url.split("#")[0]
        p.goto(base + "#servo/1")
        expect(p.locator("#message")).to_contain_text("did not answer")
        line.sim.add_device(unplugged)
        p.click("#motion-switch")  # (not check(): the page unticks it at once)
        expect(p.locator("#message")).to_have_text("read a servo first")
        expect(p.locator("#motion-switch")).not_to_be_checked()
        expect(p.locator("#jog-plus")).to_be_disabled()
        assert p.request.get(base + "api/status").json()["motion_on"] == []
        p.click("#servo-load")
        servo_read(p, 1)
        expect(p.locator("#eeprom-table [name=servo_id]")).to_have_value("1")
        p.check("#motion-switch")
        expect(p.locator("#jog-plus")).to_be_enabled()
        p.click("a[href='#line']")
        until(lambda: p.request.get(base + "api/status").json()["motion_on"] == [], "motion stayed on on the server")


def test_a_read_overtaken_by_another_servos_read_does_not_end_the_page_on_its_servo(browser: Browser) -> None:
    # Read pressed for servo 1, then for servo 3 before servo 1's values came: servo 1's read, ending last, left
    # the page on servo 1 (its values shown, its buttons acting on it) with 3 asked for last.
    line = PtyLine((1, 3))
    with web_server_page(browser, line) as p:
        p.click("a[href='#servo']")
        held: list[Route] = []
        p.route("**/api/servo/1/eeprom", lambda route: held.append(route))  # servo 1's read waits here
        p.fill("#servo-id", "1")
        p.click("#servo-load")
        deadline = time.monotonic() + GUARD
        while not held:
            assert time.monotonic() < deadline, "servo 1 was never read"
            p.wait_for_timeout(20)
        p.fill("#servo-id", "3")
        p.click("#servo-load")
        servo_read(p, 3)
        held[0].continue_()
        p.wait_for_timeout(500)  # (servo 1's read answered: the page must not turn to it)
        expect(p.locator("#page-servo")).to_have_attribute("data-loaded", "3")
        expect(p.locator("#eeprom-table [name=servo_id]")).to_have_value("3")
        p.unroute("**/api/servo/1/eeprom")


def test_opening_the_page_of_a_servo_that_does_not_answer_leaves_no_uncaught_error(browser: Browser) -> None:
    # The words are on the page; the same failure also went to the browser's console as an uncaught error.
    line = PtyLine((1,))
    with web_server_page(browser, line) as p:
        errors: list[str] = []
        p.on("pageerror", lambda error: errors.append(str(error)))
        p.goto(p.url.split("#")[0] + "#servo/4")
        expect(p.locator("#message")).to_contain_text("did not answer")
        p.wait_for_timeout(200)
        assert errors == []


def test_the_ram_box_shows_what_the_servo_has_for_the_parameter_chosen(browser: Browser) -> None:
    # The box said 127 whatever the servo had (its RAM stretch 30): Write to RAM, pressed to see what it does,
    # set the servo to the box's 127.  Stretch and speed are read from RAM; the limits cannot be read there, so
    # the box shows what the servo starts with (its EEPROM), within the limit's own range.
    line = PtyLine((4,))
    servo = line.sim.servo(4)
    servo.stretch, servo.speed = 30, 90
    with web_server_page(browser, line) as p:
        open_servo_page(p, 4)
        expect(p.locator("#ram-value")).to_have_value("30")  # (stretch, the first chosen)
        p.select_option("#ram-param", "speed")
        expect(p.locator("#ram-value")).to_have_value("90")
        p.select_option("#ram-param", "current_limit")
        expect(p.locator("#ram-value")).to_have_value(str(servo.eeprom.current_limit))
        expect(p.locator("#ram-value")).to_have_attribute("max", "63")
        p.select_option("#ram-param", "temperature_limit")
        expect(p.locator("#ram-value")).to_have_value(str(servo.eeprom.temperature_limit))
        expect(p.locator("#ram-value")).to_have_attribute("max", "127")
        p.select_option("#ram-param", "speed")
        p.fill("#ram-value", "60")
        p.click("#ram-write")
        expect(p.locator("#ram-result")).to_contain_text("speed = 60")
        expect(p.locator("#ram-value")).to_have_value("60")
        assert servo.speed == 60 and servo.stretch == 30


@pytest.mark.parametrize("typed", ["", "7.5"], ids=["emptied", "a fraction"])
def test_a_number_box_emptied_or_given_a_fraction_is_refused_in_the_pages_words(browser: Browser, typed: str) -> None:
    # Emptied (or a letter typed in: the browser then gives no value), a number box read as 0 in JavaScript: the
    # lone servo renumbered to ID 0, a punch of 0 planned, a RAM speed of 0 sent.  A fraction came back in the
    # server's names: "new_id must be an integer, got 7.5", "punch must be an int, not float".
    def refused(what: str) -> str:
        return f"give {what} a value" if typed == "" else f"{what} must be a whole number, not {typed}"

    line = PtyLine((4,))
    with web_server_page(browser, line) as p:
        open_servo_page(p, 4)
        p.fill("#eeprom-table [name=punch]", typed)
        p.click("#plan-btn")
        expect(p.locator("#message")).to_have_text(refused("punch"))
        expect(p.locator("#diff tr.changed")).to_have_count(0)
        p.fill("#ram-value", typed)
        p.click("#ram-write")
        expect(p.locator("#message")).to_have_text(refused("the RAM value"))
        p.fill("#servo-id", typed)
        p.click("#servo-load")
        expect(p.locator("#message")).to_have_text(refused("the servo's ID"))  # not "ID 0 did not answer"
        p.click("a[href='#id']")
        p.fill("#new-id", typed)
        p.click("#renumber-btn")
        expect(p.locator("#id-result")).to_have_text(refused("the new ID"))
        p.wait_for_timeout(500)  # (time for a write the page might still have sent)
        assert [s.servo_id for s in line.sim.servos] == [4]
        assert line.sim.servo(4).eeprom_writes == 0


def test_the_robot_page_refuses_an_emptied_move_time_instead_of_moving_at_once(
    browser: Browser, robot_server: RobotServer
) -> None:
    context = browser.new_context(viewport={"width": 1280, "height": 1000})
    p = context.new_page()
    with explained(p, robot_server):
        p.goto(robot_server.url)
        p.click("#robot-link")
        expect(p.locator("#robot-table tbody tr")).to_have_count(17)
        p.check("#robot-motion")
        yaw = p.locator("tr[data-joint='head_yaw']")
        expect(yaw.locator("input[type=range]")).to_be_enabled()
        target = yaw.locator(".target").text_content()
        p.fill("#robot-duration", "")
        yaw.locator("input[type=range]").fill("45")
        expect(p.locator("#message")).to_have_text("give the move time a value")
        p.wait_for_timeout(500)
        expect(yaw.locator(".target")).to_have_text(target or "")
        p.uncheck("#robot-motion")
    context.close()


def test_the_servo_page_acts_on_the_servo_it_shows_not_an_id_typed_in_the_box_and_not_read(browser: Browser) -> None:
    # Servo 1's page open, 2 typed in the ID box without Read (new servos all read alike): Show changes and
    # Write wrote servo 2 ("servo 2: written and verified") while the table showed servo 1's values.
    line = PtyLine((1, 2))
    with web_server_page(browser, line) as p:
        open_servo_page(p, 1)
        speeds = {i: line.sim.servo(i).eeprom.speed for i in (1, 2)}
        wanted = 77 if speeds[1] != 77 else 78
        p.fill("#servo-id", "2")
        p.fill("#eeprom-table [name=speed]", str(wanted))
        p.click("#plan-btn")
        expect(p.locator("#diff tr.changed")).to_contain_text(str(wanted))
        p.click("#write-btn")
        expect(p.locator("#message")).to_have_text("servo 1: written and verified")
        assert line.sim.servo(1).eeprom.speed == wanted
        assert line.sim.servo(2).eeprom.speed == speeds[2]
        # The page reads the servo it wrote again, and says which one it shows.
        expect(p.locator("#eeprom-table [name=servo_id]")).to_have_value("1")
        expect(p.locator("#servo-id")).to_have_value("1")
