"""The configurator's Line page in a real browser: scans at the line's rate and at others, servos renumbered
or gone silent, a port that cannot be opened (see ``test_web_browser.py``).
"""

from __future__ import annotations

import re
import sys
import time
from datetime import datetime, timedelta
from zoneinfo import ZoneInfo

import pytest

if not sys.platform.startswith("linux"):
    pytest.skip("the simulated pty and Debian's chromium: Linux only", allow_module_level=True)

from playwright.sync_api import Browser, expect

from ics35_async.protocol import ReadEeprom, ReadParam
from ics35_async.sim import VirtualServo
from tests.support.browser_pages import (
    SCAN_WAIT_MS,
    PtyLine,
    open_servo_page,
    scan_finds,
    scan_lists,
    web_server_page,
)
from tests.support.sim_servos import UnplugsWhenAsked

# Each module's tests share its browser (and the first module's, one page walked in order): `make test`
# hands each module whole to one xdist worker (--dist loadfile); the three modules run side by side.
pytestmark = [pytest.mark.slow, pytest.mark.pty]

# A scan asks a few IDs around the servos a test has, not all 32: each silent ID costs a probe, and on a loaded
# machine (a reply late past a probe's short wait) the scan asks every silent ID again with the whole allowance.
# The scans of every ID are the Line page's own test (test_web_browser.py).


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


def test_a_scan_at_every_rate_whose_port_is_lost_at_another_rate_lists_the_servos_it_found(browser: Browser) -> None:
    # The port went while the scan probed 625000 baud: putting the line back at its own rate then failed (no port
    # to reopen), and that failure took the scan's report with it: "the scan did not finish", the servos found at
    # 115200 dropped.  (The line comes back by itself at the rate it was lost at; the next action puts it back.)
    line = PtyLine((1, 2))
    puller = UnplugsWhenAsked(3, ReadParam, baud_rate=625000)
    line.sim.add_device(puller)
    with web_server_page(browser, line) as p:
        puller.line = line.sim
        p.check("#scan-all-bauds")
        p.fill("#scan-ids", "0-4")
        p.click("#scan-btn")
        expect(p.locator("#scan-summary")).to_contain_text(
            "2 servo(s) found before the line was lost", timeout=SCAN_WAIT_MS
        )
        expect(p.locator("#servo-table tbody tr")).to_have_count(2)
        expect(p.locator("#lost-banner")).to_be_visible()
        puller.line = None
        line.sim.replug()
        expect(p.locator("#message")).to_contain_text("the line is back")
        p.uncheck("#scan-all-bauds")
        scan_finds(p, 2, ids="0-4")
        expect(p.locator("#line-status")).to_contain_text("at 115200 baud")


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


def test_a_scan_that_finds_no_servo_at_any_rate_says_what_to_check(browser: Browser) -> None:
    # The adapter echoes, but no servo is powered on its line: the page said "0 servo(s) found." and no more.
    # The other rates were looked at after the line's own (each a whole allowance): the summary names them,
    # where it said to tick "every baud rate", as if they were still to be tried.
    line = PtyLine(())
    with web_server_page(browser, line) as p:
        scan_finds(p, 0, ids="0-4")
        expect(p.locator("#scan-summary")).to_contain_text(
            "no servo answered at 115,200 baud, nor any device at 625,000 or 1,250,000 baud"
        )
        expect(p.locator("#scan-summary")).to_contain_text("power")
        expect(p.locator("#scan-summary")).not_to_contain_text("every baud rate")
        p.check("#scan-all-bauds")
        scan_finds(p, 0, ids="0-4")
        expect(p.locator("#scan-summary")).to_contain_text("no servo answered at any baud rate")


def test_a_scan_of_ids_the_server_refuses_says_nothing_was_scanned(browser: Browser) -> None:
    # IDs "40" typed: the server refused them before anything went on the wire, and the summary said "the scan did
    # not finish", as of a scan that had started and stopped part-way.
    line = PtyLine((1,))
    with web_server_page(browser, line) as p:
        p.fill("#scan-ids", "40")
        p.click("#scan-btn")
        expect(p.locator("#message")).to_contain_text("servo ID must be in 0..31, got 40")
        expect(p.locator("#scan-summary")).to_contain_text("nothing was scanned (the message above says why)")
        expect(p.locator("#scan-summary")).not_to_contain_text("did not finish")
        scan_finds(p, 1, ids="0-4")  # (the line is as it was)


def test_the_search_of_the_other_rates_says_in_the_status_line_which_rate_it_tries(browser: Browser) -> None:
    # Nothing answers at the line's rate: the page asks the other rates, a whole allowance each where nothing answers,
    # and its status line says which (as `ics35 doctor` and `monitor --free` print it), then no more once done.
    line = PtyLine(())
    with web_server_page(browser, line) as p:
        p.fill("#scan-ids", "0-4")
        p.click("#scan-btn")
        status, summary = p.locator("#line-status"), p.locator("#scan-summary")
        # Read back to back until the scan's summary: each rate's status shows for one allowance, half a second,
        # and expect()'s polls come a second apart once it has waited a while (one fell on either side of it).
        shown: list[str] = []
        deadline = time.monotonic() + SCAN_WAIT_MS / 1000
        while "no servo answered" not in (summary.text_content() or "") and time.monotonic() < deadline:
            text = status.text_content() or ""
            if not shown or shown[-1] != text:
                shown.append(text)
        # (each rate as it is tried, as the command line says it: the first after the line's own)
        for said in ("no answer at 115200 baud: trying 625000 baud ...", "trying 1250000 baud too ..."):
            assert any(said in text for text in shown), shown
        expect(summary).to_contain_text("no servo answered at 115,200 baud")
        expect(status).not_to_contain_text("trying")


def test_the_line_page_lists_a_renumbered_servo_at_its_new_id(browser: Browser) -> None:
    line = PtyLine((0, 2))
    with web_server_page(browser, line) as p:
        scan_finds(p, 2, ids="0-5")
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
        # In ID order, as a scan lists them (ID 5 stayed in ID 0's place, above 3).
        expect(p.locator("#servo-table tbody tr").first).to_have_attribute("data-id", "3")
        expect(p.locator("#servo-table tr[data-id='5'] td.temp")).to_contain_text("°C")
        expect(p.locator("#servo-table tr[data-id='3'] td.temp")).to_contain_text("°C")
        expect(p.locator("#servo-table tr[data-id='0']")).to_have_count(0)
        expect(p.locator("#servo-table tr[data-id='2']")).to_have_count(0)


def test_a_listed_servo_that_stops_answering_is_told_in_words_not_with_its_last_values(browser: Browser) -> None:
    line = PtyLine((1, 2))
    with web_server_page(browser, line) as p:
        scan_finds(p, 2, ids="0-3")
        row = p.locator("#servo-table tr[data-id='2']")
        expect(row.locator("td.temp")).to_contain_text("°C")
        line.sim.remove_servo(2)  # its cable pulled
        # Not the library's words with the raw bytes sent, beside the last current read as if read now.
        expect(row.locator("td.temp")).to_have_text("not answering (open it to see why)")
        expect(row.locator("td.current")).to_have_text("-")
        expect(row.locator("td.temp")).to_have_attribute("title", re.compile("no reply"))


def test_a_listed_servos_open_link_stays_under_a_click_as_the_table_refreshes(browser: Browser) -> None:
    # The table was made anew about once a second: a click whose press and release straddled a refresh did nothing
    # (2 of 12 clicks held 120-150 ms), its link gone from under it.
    line = PtyLine((1, 2))
    with web_server_page(browser, line) as p:
        scan_finds(p, 2, ids="0-3")
        row = p.locator("#servo-table tr[data-id='2']")
        expect(row.locator("td.temp")).to_contain_text("°C")
        link = row.locator("a").element_handle()
        line.sim.servo(2).temperature_celsius = 61.0
        expect(row.locator("td.temp")).to_contain_text("61")  # (refreshed since the link was taken)
        assert link.evaluate("a => a.isConnected"), "the row's link was made anew"
        link.click()
        expect(p.locator("#servo-id")).to_have_value("2")


def test_a_listed_servo_that_a_second_one_at_its_id_answers_with_is_not_said_not_to_answer(browser: Browser) -> None:
    # A second new servo (ID 0, as they come) plugged in beside the first: its row said "not answering", which
    # sends a person to its power and cable, when two servos answer at once.
    line = PtyLine((0,))
    with web_server_page(browser, line) as p:
        scan_finds(p, 1, ids="0-2")
        row = p.locator("#servo-table tr[data-id='0']")
        expect(row.locator("td.temp")).to_contain_text("°C")
        line.sim.add_device(VirtualServo(0))
        expect(row.locator("td.temp")).to_have_text("answers garbled: two servos sharing ID 0?")
        expect(row.locator("td.current")).to_have_text("-")
        expect(row.locator("td.temp")).to_have_attribute("title", re.compile("sharing ID 0"))


def test_the_many_servos_page_opened_as_the_page_loads_names_the_servos_found(browser: Browser) -> None:
    # Its Servos box is filled from the servos found when it is first shown: opened as the page loaded (a reload,
    # a bookmark), before the server had said which, it stayed empty, and Apply said "choose at least one servo".
    line = PtyLine((1, 2))
    with web_server_page(browser, line) as p:
        scan_finds(p, 2, ids="0-3")
        p.goto(p.url.split("#")[0] + "#many")
        p.reload()
        expect(p.locator("#many-ids")).to_have_value("1,2")
        p.fill("#many-ids", "")  # emptied by the person: left so
        p.goto(p.url.split("#")[0] + "#line")
        expect(p.locator("#servo-table tbody tr")).to_have_count(2)
        p.goto(p.url.split("#")[0] + "#many")
        expect(p.locator("#many-ids")).to_have_value("")


def test_a_servo_found_at_another_rate_is_listed_as_not_read_at_this_one(browser: Browser) -> None:
    line = PtyLine((1,))
    line.sim.add_device(VirtualServo(5, baud_rate=1250000))
    with web_server_page(browser, line) as p:
        p.check("#scan-all-bauds")
        scan_finds(p, 2, ids="0-5")
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
        p.check("#live-free")
        p.click("#live-start")
        expect(p.locator("#legend span[data-id='1']")).to_be_visible()
        expect(p.locator("#legend span[data-id='5']")).to_have_count(0)
        p.click("#live-stop")


def test_the_traffic_pages_times_are_the_browsers_own_clock(browser: Browser) -> None:
    # The times were UTC, unlabelled: a person in Tokyo read the line's traffic nine hours off their own clock.
    line = PtyLine((1,))
    with web_server_page(browser, line, timezone_id="Asia/Tokyo") as p:
        p.click("a[href='#traffic']")  # (the recording starts with the page's first visit)
        p.click("a[href='#line']")
        scan_finds(p, 1, ids="0-2")
        p.click("a[href='#traffic']")
        first = p.locator("#traffic-table tbody tr td").first
        expect(first).to_have_text(re.compile(r"^\d\d:\d\d:\d\d\.\d{3}$"))
        now = datetime.now(ZoneInfo("Asia/Tokyo"))
        clock = {(now - timedelta(minutes=m)).strftime("%H:%M") for m in (0, 1)}
        assert (first.text_content() or "")[:5] in clock, (first.text_content(), clock)
