"""The configurator in a real browser: headless Chromium (Debian's ``chromium``, installed by ``make``)
driven by Playwright, against ``ics35 web`` run as a user runs it, on simulated servos behind a pty.

The simulated line lives in this process (served on a pty by a thread), so
every change the page makes is checked on the simulated servo itself.  Each
page's screenshot is taken; with ``ICS35_SCREENSHOTS=1`` (``make screenshots``)
it goes to ``docs/images/web-*.png``, which the docs show (a plain test run
leaves the tracked pictures alone).

The Line page's scans and renumbering are in ``test_web_browser_line.py``, the Servo, ID and live pages'
own cases in ``test_web_browser_servo.py``: three modules, run side by side.
"""

from __future__ import annotations

import contextlib
import os
import re
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

if not sys.platform.startswith("linux"):
    pytest.skip("the simulated pty and Debian's chromium: Linux only", allow_module_level=True)

from playwright.sync_api import Browser, Locator, Page, Request, Route, expect

from ics35_async.units import degrees_to_position
from tests.support.browser_pages import (
    PAGE_GONE_BOUND,
    ROOT,
    SCAN_WAIT_MS,
    WAIT_MS,
    WEB,
    PtyLine,
    backed_up,
    base_of,
    open_servo_page,
    scan_finds,
    scan_lists,
    servo_read,
    shot,
    stop_servers,
    until,
    web_server_page,
)
from tests.support.cli_runs import DUMP_ON_USR1
from tests.support.timing import PATIENT_OPTION

# Each module's tests share its browser (and the first module's, one page walked in order): `make test`
# hands each module whole to one xdist worker (--dist loadfile); the three modules run side by side.
pytestmark = [pytest.mark.slow, pytest.mark.pty]


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
def page(browser: Browser, server: str) -> Iterator[Page]:
    context = browser.new_context(viewport={"width": 1280, "height": 1000}, accept_downloads=True)
    p = context.new_page()
    p.set_default_timeout(WAIT_MS)
    p.goto(server)
    yield p
    context.close()


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
    expect(p.locator("#sim-banner")).to_contain_text("start with ics35 web --port /dev/ttyUSB0 for that")
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


def test_the_robot_page_of_a_stopped_server_shows_nothing_live(browser: Browser, tmp_path: Path) -> None:
    # Ctrl-C with the Robot page open: it went on showing motion switched on (its sliders live), "playing", and
    # the joints' last angles, temperatures and cycle as if read, under the words that the server was gone.
    robot = tmp_path / "arm.toml"
    robot.write_text(
        '[lines.arm]\nport = "sim://stopped-arm?ids=1-2&realtime=1"\nrate_hz = 50\n'
        '[joints.shoulder]\nline = "arm"\nid = 1\n[joints.elbow]\nline = "arm"\nid = 2\n'
    )
    proc = subprocess.Popen([*WEB, "--robot", str(robot)], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    assert proc.stdout is not None
    context = browser.new_context()
    p = context.new_page()
    p.goto(proc.stdout.readline().strip())
    p.click("#robot-link")
    p.check("#robot-motion")
    shoulder = p.locator("tr[data-joint='shoulder']")
    expect(shoulder.locator("input[type=range]")).to_be_enabled()
    expect(shoulder.locator(".angle")).to_have_text("0")
    proc.terminate()
    proc.wait(10)
    proc.stdout.close()
    expect(p.locator("#robot-error")).to_contain_text("server is gone")
    expect(p.locator("#robot-motion")).not_to_be_checked()
    expect(p.locator("#robot-motion")).to_be_disabled()
    expect(shoulder.locator("input[type=range]")).to_be_disabled()
    expect(shoulder.locator(".angle")).to_have_text("-")
    expect(p.locator("#robot-cycle")).to_have_text("-")
    expect(p.locator("#robot-reopen")).to_be_hidden()  # (nothing to reconnect to)
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
        # A button pressed there said the server's bare refusal ("403: wrong token: open the URL ..."), where the
        # page knows why: the same words again.
        p.click("#scan-btn")
        expect(p.locator("#message")).to_have_text(re.compile(r"^the configurator's server runs with another token"))
    finally:
        context.close()
        stop_servers(first, second)


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
    # The temperature parameter and its approximate Celsius, as the Servo page's RAM table and every command say
    # it ("41.5 °C (127)" here was a second form, its decimal a precision the parameter does not have).
    expect(ics36.locator("td.temp")).to_have_text(re.compile(r"^\d+ \(~\d+ °C\)$"))
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


def test_a_field_is_changed_written_and_verified_on_the_servo(page: Page, lines: Any) -> None:
    sim = lines[0].sim
    page.click("a[href='#line']")
    if not page.locator("#servo-table tr[data-id='1'] a").is_visible():  # (this test run alone)
        scan_finds(page, 2)
    page.click("#servo-table tr[data-id='1'] a")
    servo_read(page, 1)  # (the table can show the page's last visit before this one's reads are done)
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
    # (Target is where the servo was last sent: freed, none; held here, where it stood.  It said "8300" beside a
    # servo let go, and after Hold here.)
    expect(page.locator("#jog-target")).to_have_text("-")
    sim.servo(1).move_by_hand(8000)
    page.click("#hold-btn")
    expect(page.locator("#message")).to_contain_text("holding at 8000")
    expect(page.locator("#jog-target")).to_have_text("8000")
    assert sim.servo(1).target == 8000
    page.click("#free-btn")
    expect(page.locator("#message")).to_contain_text("free")


def test_a_jog_past_the_servos_pulse_limit_stops_there_and_says_why(page: Page, lines: Any) -> None:
    # The page kept the target at the limit without a word: +100 at the limit did nothing, and nothing said why.
    sim = lines[0].sim
    sim.servo(1).eeprom = sim.servo(1).eeprom.replace(pulse_limit_high=8350)
    sim.servo(1).move_by_hand(8200)
    open_servo(page, 1, speed=sim.servo(1).eeprom.speed)
    page.check("#motion-switch")
    expect(page.locator("#jog-target")).to_have_text("8200")
    page.click("#jog-plus")
    expect(page.locator("#jog-target")).to_have_text("8300")
    expect(page.locator("#message")).not_to_contain_text("pulse limit")
    for wanted in (8400, 8450):  # (the second from the limit's 8350)
        page.click("#jog-plus")
        expect(page.locator("#jog-target")).to_have_text("8350")
        expect(page.locator("#message")).to_contain_text(f"{wanted} is past servo 1's pulse limit 8350 (its EEPROM)")
        until(lambda: sim.servo(1).target == 8350, "the jog's command never reached servo 1")
    page.click("#free-btn")
    expect(page.locator("#message")).to_contain_text("free")


def test_renumbering_is_refused_in_words_with_two_servos_and_done_with_one(page: Page, lines: Any) -> None:
    two, lone = lines
    page.click("a[href='#id']")
    page.click("#survey-btn")
    expect(page.locator("#survey-result")).to_contain_text("not safe to renumber", timeout=SCAN_WAIT_MS)
    page.fill("#new-id", "9")
    page.click("#renumber-btn")
    expect(page.locator("#id-result")).to_contain_text("exactly one device", timeout=SCAN_WAIT_MS)
    expect(page.locator("#message")).to_be_hidden()  # said once, beside the button (it was also said on top)
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
    # A refused Apply leaves no earlier Apply's outcome under it, as if it had been this one's.
    page.uncheck("[name=use-punch]")
    page.click("#many-apply")
    expect(page.locator("#message")).to_have_text("tick at least one field to apply")
    expect(page.locator("#many-results tbody tr")).to_have_count(0)
    page.check("[name=use-punch]")
    page.click("#many-apply")
    expect(page.locator("#many-results tbody tr")).to_have_count(2)
    shot(page, "many")


def test_the_id_boxes_take_ids_as_the_command_line_does(page: Page, lines: Any) -> None:
    # The page parsed IDs itself: "5-2" went as 2..5 (the command line refuses a range that runs backwards),
    # "1 3" was refused (the command line takes it), "40" went to the server to be refused there.
    sim = lines[0].sim
    page.click("a[href='#many']")
    page.check("[name=use-punch]")
    page.fill("[name=value-punch]", "6")
    for typed, says in (("3-1", "the range '3-1' runs backwards"), ("1-40", "the range '1-40' goes beyond 0..31")):
        page.fill("#many-ids", typed)
        page.click("#many-apply")
        expect(page.locator("#message")).to_contain_text(says)
        expect(page.locator("#many-results tbody tr")).to_have_count(0)
    page.fill("#many-ids", "")
    page.click("#many-apply")
    expect(page.locator("#message")).to_have_text("name the servos to change (e.g. 1-17), or scan the line first")
    assert sim.servo(1).eeprom.punch != 6 and sim.servo(3).eeprom.punch != 6  # nothing sent
    page.fill("#many-ids", "1 3")
    page.click("#many-apply")
    expect(page.locator("#many-results tr[data-id='3']")).to_contain_text("verified")
    assert sim.servo(1).eeprom.punch == 6 and sim.servo(3).eeprom.punch == 6


def test_the_live_plot_follows_a_servo_turned_by_hand(page: Page, lines: Any) -> None:
    servo = lines[0].sim.servo(3)
    page.click("a[href='#live']")
    page.fill("#live-ids", "1,3")
    page.click("#live-start")  # (unticked: ICS 3.5 servo 1 is not freed to be read, and the page says so)
    expect(page.locator("#message")).to_contain_text("servo 1 not plotted: ICS 3.5 reads a position only by going free")
    page.check("#live-free")
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


def test_a_plot_started_again_after_a_pause_is_not_frozen(page: Page, lines: Any) -> None:
    # Pause, Stop, Start: the new plot stayed frozen on the old stream's legend (the pause outlived the stream).
    servo = lines[0].sim.servo(3)
    page.click("a[href='#live']")
    page.fill("#live-ids", "3,9")  # (9: no servo there)
    page.check("#live-free")
    page.click("#live-start")
    servo.move_by_hand(8000)
    expect(page.locator("#legend span[data-id='3']")).to_have_text("■ 3: 8000")
    # (an ID with no servo is offline, not "torque left alone (ICS 3.6)" too: it is watched for when it answers)
    expect(page.locator("#live-offline")).to_have_text("9")
    expect(page.locator("#live-watched")).to_have_text("3")  # (ICS 3.6)
    page.click("#live-pause")
    page.click("#live-stop")
    page.click("#live-start")
    expect(page.locator("#live-pause")).to_have_text("Pause")
    servo.move_by_hand(9000)
    expect(page.locator("#legend span[data-id='3']")).to_have_text("■ 3: 9000")
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


def one_line_robot(folder: Path, line: PtyLine, name: str, joints: dict[str, int], more: str = "") -> Path:
    """``folder/NAME.toml``: a robot of ``joints`` (name: servo ID, in that order) on ``line``, its line named
    ``name``; ``more``: keys of the last joint's table, then any other tables."""
    path = folder / f"{name}.toml"
    tables = "".join(f'[joints.{joint}]\nline = "{name}"\nid = {sid}\n' for joint, sid in joints.items())
    path.write_text(f'[lines.{name}]\nport = "{line.path}"\n{tables}{more}')
    return path


@contextlib.contextmanager
def arm_robot_page(
    browser: Browser, folder: Path, safety: str = "", ics36: tuple[int, ...] = ()
) -> Iterator[tuple[PtyLine, Page]]:
    """A two-joint arm (shoulder, servo 1; elbow, servo 2, -90..90; the IDs ``ics36`` speaking ICS 3.6) on a line
    of its own with ``safety`` (the robot file's table), served by ``ics35 web --robot``: its Robot page."""
    line = PtyLine((1, 2), ics36)
    robot = one_line_robot(folder, line, "arm", {"shoulder": 1, "elbow": 2}, "min = -90\nmax = 90\n" + safety)
    with web_server_page(browser, line, ["--robot", str(robot), "--yes"]) as p:
        p.click("#robot-link")
        yield line, p


@contextlib.contextmanager
def arm_with_motion_on(browser: Browser, folder: Path, safety: str) -> Iterator[tuple[PtyLine, Page]]:
    """The arm of :func:`arm_robot_page` with ``safety``, its Robot page with motion switched on."""
    with arm_robot_page(browser, folder, safety) as (line, p):
        p.check("#robot-motion")
        expect(p.locator("#robot-state")).to_contain_text("joints hold where they stand")
        yield line, p


def test_a_joint_freed_for_over_current_is_reset_on_the_robot_page_and_moves_again(
    browser: Browser, tmp_path: Path
) -> None:
    # A free servo draws no current, so a current trip of a joint the watch freed stands until the person says
    # its cause is dealt with: the joint's Reset button, and nothing else, lets it move again.
    with arm_with_motion_on(browser, tmp_path, '[safety]\nmax_current = 20\naction = "free"\n') as (line, p):
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


def test_the_robot_pages_sliders_show_where_their_joints_are_and_a_refusal_goes_with_the_next_move(
    browser: Browser, tmp_path: Path
) -> None:
    # A refused slider move left the slider where it was put (the joint's target elsewhere); the refusal stayed
    # at the top of the page after the next slider move had gone out; and a free joint's slider stood at the
    # target it had before it was freed, wherever the joint was turned since.
    with arm_with_motion_on(browser, tmp_path, '[safety]\naction = "hold"\n') as (line, p):
        shoulder, elbow = p.locator("tr[data-joint='shoulder']"), p.locator("tr[data-joint='elbow']")
        expect(elbow.locator(".target")).not_to_have_text("free")
        held = elbow.locator(".target").text_content() or ""
        line.sim.remove_servo(2)
        expect(elbow.locator(".angle")).to_have_text("offline")
        elbow.locator("input[type=range]").fill("40")
        expect(p.locator("#message")).to_contain_text("offline")
        expect(elbow.locator("input[type=range]")).to_have_value(held)
        shoulder.locator("input[type=range]").fill("20")
        expect(shoulder.locator(".target")).to_have_text("20")
        expect(p.locator("#message")).to_be_hidden()
        p.click("#robot-free")
        expect(shoulder.locator(".target")).to_have_text("free")
        # (The page says "free" once the robot's target is; its servo is free once the command is on the wire: a
        # servo turned by hand before then turns back to 20.)
        until(lambda: line.sim.servo(1).free, "the shoulder was never freed")
        line.sim.servo(1).move_by_hand(degrees_to_position(-25))
        expect(shoulder.locator("input[type=range]")).to_have_value("-25")


def test_an_ics36_joint_only_read_shows_no_target_as_the_live_table_shows_it(browser: Browser, tmp_path: Path) -> None:
    # An ICS 3.6 joint is read at the open and left as it was found (its torque unknown, no target sent): its row
    # said "free", where `ics35 play`'s live table shows "-".  An ICS 3.5 joint, freed to be read, is free.
    with arm_robot_page(browser, tmp_path, ics36=(2,)) as (_, p):
        shoulder, elbow = p.locator("tr[data-joint='shoulder']"), p.locator("tr[data-joint='elbow']")
        expect(elbow.locator(".angle")).not_to_have_text("-")  # (read: the robot is streaming)
        expect(elbow.locator(".target")).to_have_text("-")
        expect(shoulder.locator(".target")).to_have_text("free")
        p.check("#robot-motion")  # (both held where they stand: a target each)
        expect(p.locator("#robot-state")).to_contain_text("joints hold where they stand")
        for row in (shoulder, elbow):
            expect(row.locator(".target")).not_to_have_text(re.compile(r"^(-|free)$"))


@contextlib.contextmanager
def elbow_gone_offline(browser: Browser, tmp_path: Path) -> Iterator[tuple[PtyLine, Page, Locator, Any, str]]:
    """The arm of :func:`arm_with_motion_on`, played on past a servo gone offline (``continue_on_offline``), its
    elbow held and then its servo unplugged: the line, the page, the elbow's row, its servo (off the line) and
    where the elbow's slider stood before."""
    with arm_with_motion_on(browser, tmp_path, "[safety]\ncontinue_on_offline = true\n") as (line, p):
        until(lambda: not line.sim.servo(2).free, "the elbow was never held")
        elbow = p.locator("tr[data-joint='elbow']")
        expect(elbow.locator(".target")).not_to_have_text("-")
        slider = elbow.locator("input[type=range]").input_value()
        servo = line.sim.remove_servo(2)
        expect(elbow.locator(".angle")).to_have_text("offline")
        yield line, p, elbow, servo, slider


def test_an_offline_joints_target_is_shown_as_not_sent_as_the_live_table_shows_it(
    browser: Browser, tmp_path: Path
) -> None:
    # A joint whose servo stopped answering (continue_on_offline: the watch lets the robot play on) is sent nothing,
    # but its row showed its target as if it were held there; `ics35 play`'s live table shows "-" for it.
    with elbow_gone_offline(browser, tmp_path) as (_, p, elbow, _, slider):
        expect(elbow.locator(".target")).to_have_text("-")
        for cell in (".temp", ".current"):
            expect(elbow.locator(cell)).to_have_text("-")
        expect(elbow.locator("input[type=range]")).to_have_value(slider)  # (at the target it had)
        expect(p.locator("tr[data-joint='shoulder'] .target")).not_to_have_text("-")


def test_a_joint_held_since_its_servo_answered_again_is_freed_from_its_row_and_moved_again(
    browser: Browser, tmp_path: Path
) -> None:
    # A servo that stopped answering and came back (continue_on_offline: the watch let the robot play on) is
    # held, sent nothing: it may have restarted, free, elsewhere.  Its slider's move was refused only in the
    # state line, in the library's words ("set its target (set_targets) or free it first"), and the page had no
    # way out but Free all (every joint limp).  The refusal is the move's answer now, in the page's words, and
    # the joint's row has a Free button: freed (read where it stands), it moves again from there.
    with elbow_gone_offline(browser, tmp_path) as (line, p, elbow, servo, _):
        line.sim.add_device(servo)
        expect(elbow.locator(".target")).to_contain_text("held: rejoined")
        target = servo.target
        elbow.locator("input[type=range]").fill("30")
        expect(p.locator("#message")).to_contain_text("joint elbow is held")
        expect(p.locator("#message")).to_contain_text("Free")
        expect(p.locator("#message")).not_to_contain_text("set_targets")
        assert servo.target == target  # nothing sent
        elbow.get_by_role("button", name="Free").click()
        until(lambda: line.sim.servo(2).free, "the elbow was not freed")
        expect(elbow.locator(".target")).to_have_text("free")
        assert not line.sim.servo(1).free  # the shoulder holds on
        elbow.locator("input[type=range]").fill("30")
        expect(elbow.locator(".target")).to_have_text("30")
        until(lambda: not line.sim.servo(2).free, "the elbow was not moved again")


def test_the_robot_page_says_a_lost_line_and_reconnects_when_it_is_back(browser: Browser, tmp_path: Path) -> None:
    # The page said nothing and kept saying "open" after a line was lost; only a restart brought it back.
    # shoulder on an ICS 3.6 servo (read again at a reconnect), elbow on an ICS 3.5 one (asked about).
    line = PtyLine((1, 2), ics36=(1,))
    line.sim.servo(2).command_position(7000)  # (bearing the arm as the server starts)
    robot = one_line_robot(tmp_path, line, "arm", {"shoulder": 1, "elbow": 2})
    with web_server_page(browser, line, ["--robot", str(robot)]) as p:
        p.click("#robot-link")
        # The server's start freed nothing: the Robot page asks before it frees elbow to read it (ICS 3.5).
        expect(p.locator("#robot-start-free-question")).to_contain_text("Joint elbow speaks ICS 3.5")
        expect(p.locator("#robot-start-free-question")).to_contain_text("--start-pose stating where it stands")
        expect(p.locator("#robot-error")).to_contain_text("the robot is not open, nothing freed")
        expect(p.locator('tr[data-joint="elbow"] .target')).to_have_text("-")  # (not "free": it bears the arm)
        # (nothing read, nothing watched: not "ok", not "all within limits")
        expect(p.locator('tr[data-joint="elbow"] .safety')).to_have_text("-")
        expect(p.locator("#robot-state")).to_have_text("not open")
        expect(p.locator("#robot-reopen")).to_be_hidden()
        assert line.sim.servo(2).target == 7000
        p.click("#robot-start-free")
        expect(p.locator("#robot-cycle")).not_to_have_text("-")
        expect(p.locator("#robot-start-free-choice")).to_be_hidden()
        expect(p.locator("#robot-state")).to_contain_text("opened: elbow freed to read where it stands")
        expect(p.locator('tr[data-joint="elbow"] .safety')).to_have_text("ok")
        expect(p.locator("#robot-error")).to_have_text("")
        assert line.sim.servo(2).free
        expect(p.locator("#robot-reopen")).to_be_hidden()
        # (Once the robot has read where elbow stands: on a loaded machine its first cycles may not have, and
        # motion on leaves a joint not read yet as it is.)
        expect(p.locator('tr[data-joint="elbow"] .angle')).to_have_text(re.compile(r"^-?\d"))
        p.check("#robot-motion")  # the joints hold where they stand: elbow's servo holds a target
        expect(p.locator("#robot-state")).to_contain_text("joints hold where they stand")
        until(lambda: line.sim.servo(2).target is not None, "elbow's servo never got a target")
        elbow = line.sim.servo(2).target
        line.sim.unplug()
        expect(p.locator("#robot-error")).to_contain_text("lost")
        expect(p.locator("#robot-reopen-choice")).to_be_visible()  # elbow held a target: the page asks
        # (one joint: its grammar, not "elbow had targets their servos may no longer hold")
        question = "Line arm was lost. elbow had a target its servo may no longer hold"
        expect(p.locator("#robot-reopen-question")).to_contain_text(question)
        expect(p.locator("#robot-reopen-question")).to_contain_text("If its servo kept its power it still holds it")
        expect(p.locator("#robot-reopen")).to_be_hidden()
        expect(p.locator("#robot-motion")).to_be_disabled()
        line.sim.replug()
        p.click("#robot-reopen-hold")
        expect(p.locator("#robot-reopen-choice")).to_be_hidden()
        expect(p.locator("#robot-start-free-choice")).to_be_hidden()  # (asked once: before the first open)
        expect(p.locator("#robot-reopen")).to_be_hidden()
        expect(p.locator("#robot-error")).to_have_text("")
        assert line.sim.servo(2).target == elbow and not line.sim.servo(2).free  # never went limp
        line.sim.unplug()  # again, with motion off now: the same question, and the plain button stays hidden
        expect(p.locator("#robot-reopen-choice")).to_be_visible()
        line.sim.replug()
        p.click("#robot-reopen-free")
        expect(p.locator("#robot-reopen-choice")).to_be_hidden()
        expect(p.locator("#robot-start-free-choice")).to_be_hidden()  # (the person said so: nothing more asked)
        until(lambda: line.sim.servo(2).free, "elbow's servo was not freed")
        expect(p.locator("#robot-error")).to_have_text("")
        expect(p.locator("#robot-motion")).to_be_enabled()
        p.check("#robot-motion")  # and the robot answers again: motion on, the joints held where they stand
        expect(p.locator("#robot-state")).to_contain_text("joints hold where they stand")


def test_a_joint_silent_at_the_robots_open_comes_back_held_with_its_free_button_not_freed(
    browser: Browser, tmp_path: Path
) -> None:
    # Its probe, the free command, freed it the moment it answered, unasked: a knee whose signal wire was loose
    # while it held the robot up went limp.  It comes back held, sent nothing, and the page's Free frees it.
    line = PtyLine((1, 2))
    for servo in line.sim.servos:
        servo.command_position(7000)
    knee = line.sim.remove_servo(2)
    robot = one_line_robot(tmp_path, line, "legs", {"hip": 1, "knee": 2})
    with web_server_page(browser, line, ["--robot", str(robot)]) as p:
        p.click("#robot-link")
        expect(p.locator("#robot-start-free-question")).to_contain_text("Joint hip speaks ICS 3.5")
        p.click("#robot-start-free")
        row = p.locator('tr[data-joint="knee"]')
        expect(row.locator(".angle")).to_have_text("offline")
        line.sim.add_device(knee)  # (its replies back: it had kept its power and target)
        expect(row.locator(".target")).to_contain_text("- (held: rejoined, sent nothing)")
        assert knee.target == 7000
        row.get_by_role("button", name="Free").click()
        until(lambda: knee.free, "the knee was not freed by its Free button")
        expect(row.locator(".target")).to_have_text("free")


def test_the_simulator_banner_is_not_shown_over_a_real_robots_question(browser: Browser, tmp_path: Path) -> None:
    # While the robot waits for its question the pages stand on sim://: the banner over the Robot page said
    # "nothing here moves real hardware" right above the button that frees the real robot's joints.
    line = PtyLine((1,))
    robot = one_line_robot(tmp_path, line, "legs", {"hip": 1})
    with web_server_page(browser, line, ["--robot", str(robot)]) as p:
        expect(p.locator("#sim-banner")).to_be_visible()  # (the Line page: on sim:// meanwhile)
        p.click("#robot-link")
        expect(p.locator("#robot-start-free-question")).to_contain_text("Joint hip speaks ICS 3.5")
        expect(p.locator("#sim-banner")).to_be_hidden()
        p.evaluate("location.hash = '#line'")
        expect(p.locator("#sim-banner")).to_be_visible()


def test_reconnect_asks_before_freeing_a_joint_that_came_back_held(browser: Browser, tmp_path: Path) -> None:
    # The knee, silent at the open, came back held (sent nothing: its servo bears what it bore).  The line lost
    # and back, Reconnect read it by freeing it, unasked; now the page asks, as at the robot's first open.
    line = PtyLine((1, 2))
    knee = line.sim.remove_servo(2)
    knee.command_position(7000)
    robot = one_line_robot(tmp_path, line, "legs", {"hip": 1, "knee": 2})
    with web_server_page(browser, line, ["--robot", str(robot)]) as p:
        p.click("#robot-link")
        p.click("#robot-start-free")
        row = p.locator('tr[data-joint="knee"]')
        expect(row.locator(".angle")).to_have_text("offline")
        line.sim.add_device(knee)
        expect(row.locator(".target")).to_contain_text("- (held: rejoined, sent nothing)")
        line.sim.unplug()
        expect(p.locator("#robot-reopen")).to_be_visible()
        line.sim.replug()
        expect(p.locator("#robot-error")).to_contain_text("press Reconnect")
        p.click("#robot-reopen")
        expect(p.locator("#robot-start-free-question")).to_contain_text("Joint knee speaks ICS 3.5")
        expect(p.locator("#robot-reopen")).to_be_hidden()
        assert knee.target == 7000 and not knee.free  # (the hip, free since the open, is not asked about)
        p.click("#robot-start-free")
        until(lambda: knee.free, "the knee was not freed by the page's answer")
        expect(p.locator("#robot-state")).to_contain_text("reconnected; knee freed to read where it stands")
        expect(p.locator("#robot-start-free-choice")).to_be_hidden()


def test_reconnect_pressed_before_the_line_is_back_is_told_when_it_is_back(browser: Browser, tmp_path: Path) -> None:
    # Pressed too early, Reconnect's "line arm is still lost" stayed on after the port was back; the banner over
    # every page said the port reconnects "as soon as it returns", where the robot waits for Reconnect.
    with arm_robot_page(browser, tmp_path) as (line, p):
        expect(p.locator("#robot-cycle")).not_to_have_text("-")
        line.sim.unplug()
        expect(p.locator("#robot-reopen")).to_be_visible()
        expect(p.locator("#lost-banner")).to_be_visible()
        # (not "it reconnects as soon as the port returns, then press Reconnect": which of the two brings it back?)
        expect(p.locator("#lost-banner")).to_contain_text(
            "plug it back in (the line reopens by itself; the robot waits), then press Reconnect on the Robot page"
        )
        p.click("#robot-reopen")
        expect(p.locator("#message")).to_contain_text("line arm is still lost")
        line.sim.replug()
        expect(p.locator("#message")).to_have_text("line arm is back: press Reconnect")
        expect(p.locator("#robot-error")).to_contain_text("line arm is back: press Reconnect")
        expect(p.locator("#lost-banner")).to_be_hidden()
        p.click("#robot-reopen")
        expect(p.locator("#robot-error")).to_have_text("")
        expect(p.locator("#robot-cycle")).not_to_have_text("-")


def test_free_all_while_a_line_is_lost_frees_the_other_line_and_names_the_joints_it_could_not_reach(
    browser: Browser, tmp_path: Path
) -> None:
    # A lost line closed the robot, and Free all was refused, while the other line's joints held their last
    # targets: a robot half-stopped could not be made limp at once.
    upper, lower = PtyLine((1,)), PtyLine((1, 2))
    robot = tmp_path / "two.toml"
    robot.write_text(
        f'[lines.upper]\nport = "{upper.path}"\n[lines.lower]\nport = "{lower.path}"\n'
        '[joints.neck]\nline = "upper"\nid = 1\n[joints.hip]\nline = "lower"\nid = 1\n'
        '[joints.knee]\nline = "lower"\nid = 2\n'
    )
    try:
        with web_server_page(browser, upper, ["--robot", str(robot), "--yes"]) as p:
            p.click("#robot-link")
            for name in ("neck", "hip", "knee"):  # (read, so that motion on holds them where they stand)
                expect(p.locator(f'tr[data-joint="{name}"] .angle')).to_have_text(re.compile(r"^-?\d"))
            p.check("#robot-motion")
            expect(p.locator("#robot-state")).to_contain_text("joints hold where they stand")
            servos = (upper.sim.servo(1), lower.sim.servo(1), lower.sim.servo(2))
            until(lambda: not any(servo.free for servo in servos), "the joints never held")
            lower.sim.unplug()
            expect(p.locator("#robot-error")).to_contain_text("lost")
            expect(p.locator("#robot-reopen-choice")).to_be_visible()
            question = "Line lower was lost. hip, knee had targets their servos may no longer hold"
            expect(p.locator("#robot-reopen-question")).to_contain_text(question)
            p.click("#robot-stop")  # (it said nothing: the robot is not open, nothing plays)
            expect(p.locator("#message")).to_contain_text("nothing to stop: the robot is not open")
            expect(p.locator("#message")).to_contain_text("Free all")
            p.click("#robot-free")
            expect(p.locator("#robot-state")).to_contain_text("hip, knee not reached")
            expect(p.locator("#robot-state")).to_contain_text("their servos may still hold")
            until(lambda: upper.sim.servo(1).free, "the neck was not freed")
            assert not lower.sim.servo(1).free and not lower.sim.servo(2).free  # (their line is lost)
            expect(p.locator('tr[data-joint="neck"] .target')).to_have_text("free")
            # (not shown "free" while their servos may still hold: when they go free, said)
            expect(p.locator('tr[data-joint="hip"] .target')).to_have_text("free once line lower is back")
            # Reconnect follows the freeing: nothing to ask about, and it frees the joint it could not reach.
            expect(p.locator("#robot-reopen-choice")).to_be_hidden()
            expect(p.locator("#robot-reopen")).to_be_visible()
            lower.sim.replug()
            p.click("#robot-reopen")
            expect(p.locator("#robot-error")).to_have_text("")
            expect(p.locator("#robot-state")).to_contain_text("hip, knee freed")
            until(lambda: all(servo.free for servo in servos), "the lower line was not freed once it was back")
            assert upper.sim.servo(1).free
    finally:
        lower.close()


def test_the_robot_page_of_a_server_started_again_with_a_new_token_shows_nothing_live(
    browser: Browser, tmp_path: Path
) -> None:
    # The server stopped and started again with a new token before the page had noticed: the page said to open the
    # new address, but its Robot page went on showing motion on (its sliders live) and the joints' angles as read.
    with socket.socket() as probe:  # a free port, for both servers: the page comes back to the same address
        probe.bind(("127.0.0.1", 0))
        listen = f"127.0.0.1:{probe.getsockname()[1]}"
    robot = tmp_path / "arm.toml"
    robot.write_text(
        '[lines.arm]\nport = "sim://again-arm?ids=1-2&realtime=1"\nrate_hz = 50\n'
        '[joints.shoulder]\nline = "arm"\nid = 1\n[joints.elbow]\nline = "arm"\nid = 2\n'
    )
    environment = {k: v for k, v in os.environ.items() if k not in ("ICS35_PORT", "ICS35_WEB_TOKEN")}

    def start() -> tuple[subprocess.Popen[str], str]:
        command = [*WEB, "--listen", listen, "--robot", str(robot)]
        proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, env=environment)
        assert proc.stdout is not None
        return proc, proc.stdout.readline().strip()

    first, url = start()
    second: subprocess.Popen[str] | None = None
    context = browser.new_context()

    def restarted_first(route: Route) -> None:
        # The page asks the server's status once its socket closes: the new server answers it, as it does when
        # the restart is quicker than the page.
        nonlocal second
        if first.poll() is not None and second is None:
            second, _ = start()
        route.continue_()

    try:
        p = context.new_page()
        p.goto(url)
        p.route("**/api/status", restarted_first)
        p.click("#robot-link")
        p.check("#robot-motion")
        shoulder = p.locator("tr[data-joint='shoulder']")
        expect(shoulder.locator("input[type=range]")).to_be_enabled()
        expect(shoulder.locator(".angle")).to_have_text("0")
        first.terminate()
        first.wait(10)
        expect(p.locator("#line-status")).to_have_text("server started again: open its new address")
        expect(p.locator("#robot-error")).to_contain_text("another token")
        expect(p.locator("#robot-motion")).not_to_be_checked()
        expect(p.locator("#robot-motion")).to_be_disabled()
        expect(shoulder.locator("input[type=range]")).to_be_disabled()
        expect(shoulder.locator(".angle")).to_have_text("-")
        expect(p.locator("#robot-reopen")).to_be_hidden()  # (nothing this page can reconnect to)
    finally:
        context.close()
        stop_servers(first, second)


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


# The robot's server streams its 17 joints for as long as it runs (about a third of a core): its tests come last,
# together, so it is started after every other test here and stopped with the module (a test of its own server put
# after them would pay for that stream all along).
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


@contextlib.contextmanager
def robot_server_page(browser: Browser, server: RobotServer, **context: Any) -> Iterator[Page]:
    """A new page on the robot server's configurator, its failures explained (see :func:`explained`)."""
    ctx = browser.new_context(**context)
    p = ctx.new_page()
    with explained(p, server):
        p.goto(server.url)
        yield p
    ctx.close()


def test_the_robot_page_moves_a_joint_and_plays_a_motion(browser: Browser, robot_server: RobotServer) -> None:
    with robot_server_page(browser, robot_server, viewport={"width": 1280, "height": 1000}) as p:
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


def test_a_motion_file_that_is_not_json_is_said_to_be_no_motion(
    browser: Browser, robot_server: RobotServer, tmp_path: Path
) -> None:
    # "notes.txt: not JSON (Unexpected token 'o', "not json" is not valid JSON)": the browser parser's words.
    with robot_server_page(browser, robot_server) as p:
        p.click("#robot-link")
        p.check("#robot-motion")
        (tmp_path / "notes.txt").write_text("not json")
        p.set_input_files("#robot-motion-file", str(tmp_path / "notes.txt"))
        p.click("#robot-play")
        expect(p.locator("#message")).to_have_text(
            "notes.txt is no motion: not JSON (a motion is the .json file ics35 teach writes)"
        )


def test_ticking_enable_motion_stays_ticked_while_the_server_has_not_answered(
    browser: Browser, robot_server: RobotServer
) -> None:
    # The robot's state comes pushed several times a second, saying motion is off until the server
    # has taken the tick: the box must not flip back meanwhile (a user would see it untick itself).
    with robot_server_page(browser, robot_server) as p:
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
    with robot_server_page(browser, robot_server, viewport={"width": 1280, "height": 1000}) as p:
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


def test_on_a_robot_line_the_simulator_banner_points_at_the_robot_file_not_at_port(
    browser: Browser, robot_server: RobotServer
) -> None:
    # A robot's lines come from its file (--port opens another line beside them): the banner sent a builder of a
    # simulated robot to `ics35 web --port`, which leaves the robot simulated.
    with robot_server_page(browser, robot_server) as p:
        banner = p.locator("#sim-banner")
        for line in ("upper", "legs"):  # (the server's line is what the tests before left it on)
            p.click(f"#robot-lines-table tr[data-line='{line}'] button")
            expect(p.locator("#line-status")).to_contain_text(f"the robot's line {line}")
            expect(banner).to_contain_text(f'for that: port = "/dev/ttyUSB0" in the robot file\'s [lines.{line}]')
            expect(banner).not_to_contain_text("--port")


def test_the_robot_page_refuses_an_emptied_move_time_instead_of_moving_at_once(
    browser: Browser, robot_server: RobotServer
) -> None:
    with robot_server_page(browser, robot_server, viewport={"width": 1280, "height": 1000}) as p:
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
