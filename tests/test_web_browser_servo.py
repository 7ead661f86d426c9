"""The configurator's Servo, ID, Many servos and Live plots pages in a real browser, each case on a line and
server of its own: backups and restores, ticks, motion switched on and off, jogs, servos that stop answering
(see ``test_web_browser.py``).
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

if not sys.platform.startswith("linux"):
    pytest.skip("the simulated pty and Debian's chromium: Linux only", allow_module_level=True)

from playwright.sync_api import Browser, Page, Route, expect

from ics35_async.eeprom import Eeprom
from ics35_async.policies.eeprom_backup import backups_in
from ics35_async.protocol import ReadEeprom, WriteEeprom
from ics35_async.sim import VirtualServo
from tests.support.browser_pages import (
    PAGE_GONE_BOUND,
    WEB,
    PtyLine,
    backed_up,
    open_servo_page,
    scan_finds,
    servo_read,
    stop_servers,
    until,
    until_on,
    web_server_page,
)
from tests.support.sim_servos import TakesTheWriteSilently, UnpluggedAfterWrite, UnplugsWhenAsked
from tests.support.timing import GUARD, PATIENT_OPTION

# Each module's tests share its browser (and the first module's, one page walked in order): `make test`
# hands each module whole to one xdist worker (--dist loadfile); the three modules run side by side.
pytestmark = [pytest.mark.slow, pytest.mark.pty]


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


def test_the_servo_page_says_what_a_write_leaves_for_the_next_power_up_and_what_a_restore_keeps(
    browser: Browser, tmp_path: Path
) -> None:
    line = PtyLine((1, 2))
    servo = line.sim.servo(1)
    raw = bytearray(servo.eeprom.to_bytes())
    raw[15] |= 0x02  # FREE, as a servo reports its state
    servo.eeprom = Eeprom.from_bytes(bytes(raw))
    with web_server_page(browser, line) as p:
        open_servo_page(p, 1)
        p.fill("#eeprom-table [name=speed]", "50")
        p.click("#plan-btn")
        expect(p.locator("#diff tr.changed")).to_contain_text("50")
        p.click("#write-btn")
        expect(p.locator("#write-result")).to_contain_text(
            "speed: loaded into RAM at the servo's next power-up; to use it now: Write to RAM speed 50"
        )
        backup = backed_up(p, tmp_path)
        open_servo_page(p, 2)
        line.sim.servo(2).eeprom = line.sim.servo(2).eeprom.replace(speed=50)  # only FREE differs
        p.set_input_files("#restore-file", str(backup))
        expect(p.locator("#restore-diff")).to_contain_text("no change")
        expect(p.locator("#restore-diff")).to_contain_text(
            "servo 2 keeps its read-only flag(s) as it reports them (FREE off)"
        )


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
        # (the browser's parser's words, "Unexpected token 'o', "not json" is not valid JSON", say nothing of backups)
        expect(p.locator("#message")).to_have_text(
            "notes.txt is no EEPROM backup: not JSON (a backup is the .json file Back up saves)"
        )
        expect(p.locator("#restore-diff")).to_be_empty()
        expect(p.locator("#restore-btn")).to_be_disabled()


def start_live_plot(p: Page, ids: str) -> None:
    """The Live plots page of ``p``'s server, streaming ``ids`` (as typed in its IDs box)."""
    p.goto(p.url.split("#")[0] + "#live")
    p.fill("#live-ids", ids)
    p.check("#live-free")  # (ICS 3.5 servos: read by going free)
    p.click("#live-start")


def test_a_stopped_live_plot_no_longer_shows_the_streams_rate_as_now(browser: Browser) -> None:
    # Stop left "stream 99.8 cycles/s, page 26 updates/s" on show for good, as if it still ran.
    line = PtyLine((1,))
    with web_server_page(browser, line) as p:
        start_live_plot(p, "1")
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


def test_the_live_plots_words_on_servos_not_plotted_or_held_say_servos_of_several(browser: Browser) -> None:
    # "servo 5, 6 not plotted: ... to plot them limp": one servo's words, of two.
    line = PtyLine((5, 6, 7), ics36=(7,))
    with web_server_page(browser, line) as p:
        p.goto(p.url.split("#")[0] + "#live")
        for ids, said in (
            ("5-7", 'servos 5, 6 not plotted: ICS 3.5 reads a position only by going free (tick "free ICS 3.5 servos" '
             "to plot them limp)"),
            ("5,7", 'servo 5 not plotted: ICS 3.5 reads a position only by going free (tick "free ICS 3.5 servos" '
             "to plot it limp)"),
            ("5,6", "servos 5, 6 speak ICS 3.5, which reads a position only by going free (limp): tick "
             '"free ICS 3.5 servos" to plot them'),
            ("6", 'servo 6 speaks ICS 3.5, which reads a position only by going free (limp): tick "free ICS 3.5 '
             'servos" to plot it (turn it by hand)'),
        ):  # fmt: skip
            p.fill("#live-ids", ids)
            p.click("#live-start")
            expect(p.locator("#message")).to_contain_text(said)
            p.click("#live-stop")
        base = p.url.split("#")[0]
        for held in ("5", "5,6"):
            for sid in held.split(","):  # (Hold, as its page sends it once it has read the servo's limits)
                assert p.request.get(f"{base}api/servo/{sid}/eeprom").status == 200
                held_now = p.request.post(f"{base}api/servo/{sid}/hold", data={})
                assert held_now.status == 200, held_now.text()
            p.fill("#live-ids", "5-7")
            p.check("#live-free")
            p.click("#live-start")
            one = held == "5"
            said = "servo 5: held by its Servo page, so streamed its target" if one else (
                "servos 5, 6: held by their Servo pages, so streamed their targets")  # fmt: skip
            expect(p.locator("#message")).to_contain_text(said)
            p.click("#live-stop")


def test_a_live_plot_whose_port_is_lost_no_longer_shows_the_streams_rate_as_now(browser: Browser) -> None:
    # The adapter pulled mid-plot: the page went on saying "stream 99.9 cycles/s, page 26 updates/s" (the same
    # last frame pushed again and again), its cycle standing still, as if the servos were read.
    line = PtyLine((1,))
    with web_server_page(browser, line) as p:
        start_live_plot(p, "1")
        expect(p.locator("#live-updates")).to_have_text(re.compile(r"^[1-9]\d*$"))
        line.sim.unplug()
        expect(p.locator("#lost-banner")).to_be_visible()
        expect(p.locator("#live-cycle")).to_contain_text("the port is lost")
        expect(p.locator("#live-rate")).to_have_text("-")
        expect(p.locator("#live-updates")).to_have_text("0")
        line.sim.replug()
        expect(p.locator("#lost-banner")).to_be_hidden()
        expect(p.locator("#live-updates")).to_have_text(re.compile(r"^[1-9]\d*$"))
        expect(p.locator("#live-rate")).to_have_text(re.compile(r"^\d"))
        expect(p.locator("#live-cycle")).not_to_contain_text("lost")
        p.click("#live-stop")


def test_the_live_target_legend_says_free_and_left_alone_not_0_and_minus_1(browser: Browser) -> None:
    # The target plot's legend gave the stream's own marks as if they were positions: "1: 0" for a servo it
    # frees, "3: -1" for an ICS 3.6 servo it only reads; and the free servo's 0 was drawn, squashing the rest.
    line = PtyLine((1, 3), ics36=(3,))
    with web_server_page(browser, line) as p:
        start_live_plot(p, "1,3")
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
    # The refusal names the change and the allowance; the page names the tick that gives it.
    line = PtyLine((1,))
    with web_server_page(browser, line) as p:
        open_servo_page(p, 1)
        p.fill("#eeprom-table [name=servo_id]", "7")
        p.click("#plan-btn")
        expect(p.locator("#diff .refusal")).to_contain_text("the image changes its ID to 7")
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
        until_on(p, lambda: bool(held), "the jog was never asked")
        off = p.request.post(p.url.split("#")[0] + "api/servo/1/motion", data={"enabled": False})
        assert off.status == 200, off.text()
        held[0].continue_()
        expect(p.locator("#message")).to_contain_text("motion is not enabled for servo 1")
        expect(p.locator("#jog-target")).to_have_text("8000")  # the last target sent, not the refused one
        expect(p.locator("#jog-slider")).to_have_value("8000")
        assert servo.target == 8000
        p.unroute("**/api/servo/1/move")


def test_a_jog_that_found_its_servo_off_its_way_shows_it_freed_not_at_its_last_target(browser: Browser) -> None:
    # The server freed the servo (it had restarted and been turned: the jog's reply came from 9000) and said so,
    # but the page went on showing Target 8000 beside motion off until the next read.
    with held_by_its_page(browser, 8000) as (_, servo, p):
        until(lambda: servo.target == 8000, "enable motion never held servo 1")
        servo.power_cycle()  # (quicker than the page's poll)
        servo.move_by_hand(9000)
        p.click("#jog-plus")
        expect(p.locator("#message")).to_contain_text("it was freed at once")
        expect(p.locator("#jog-target")).to_have_text("-")
        expect(p.locator("#jog-position")).to_have_text(re.compile(r"^(89|90)\d\d$"))
        expect(p.locator("#motion-switch")).not_to_be_checked()
        expect(p.locator("#jog-plus")).to_be_disabled()
        assert servo.free


def test_a_jog_whose_answer_was_lost_shows_its_target_as_uncertain(browser: Browser) -> None:
    # A servo that did not answer the jog (504) may have heard it: its target is the new one or the old.
    with held_by_its_page(browser, 8000) as (line, _, p):
        line.sim.remove_servo(1)  # its cable pulled: the jog goes out, no answer comes back
        with p.expect_response("**/api/servo/1/move") as answer:
            p.click("#jog-plus")
        assert answer.value.status == 504, answer.value.text()
        expect(p.locator("#jog-target")).to_have_text("8100? (not confirmed)")
        expect(p.locator("#jog-target")).to_have_attribute("title", re.compile("may"))


def write_or_restore_shown(p: Page, line: PtyLine, tmp_path: Path, how: str) -> tuple[str, str]:
    """Servo 1's page with a write of speed 90 (``how`` "write") or a restore of its backup over speed 33
    ("restore") shown and ready: its button and where its outcome goes."""
    open_servo_page(p, 1)
    if how == "write":
        p.fill("#eeprom-table [name=speed]", "90")
        p.click("#plan-btn")
        button, result = "#write-btn", "#write-result"
    else:
        backup = backed_up(p, tmp_path)
        line.sim.servo(1).eeprom = line.sim.servo(1).eeprom.replace(speed=33)
        p.set_input_files("#restore-file", str(backup))
        button, result = "#restore-btn", "#restore-result"
    expect(p.locator(button)).to_be_enabled()
    return button, result


@pytest.mark.parametrize("how", ["write", "restore"])
def test_a_write_whose_read_after_fails_still_shows_its_outcome(browser: Browser, tmp_path: Path, how: str) -> None:
    # The server stopped (Ctrl-C) as it answered the write: the write was verified, but the page read the servo
    # again before showing it, that read failed, and the page said only "the server does not answer".
    line = PtyLine((1,))
    with web_server_page(browser, line) as p:
        button, result = write_or_restore_shown(p, line, tmp_path, how)
        p.route("**/api/servo/1/eeprom", lambda route: route.abort())  # the read after it fails as with no server
        p.click(button)
        expect(p.locator("#message")).to_contain_text("the configurator's server does not answer")
        expect(p.locator(result)).to_contain_text("written and verified by reading it back")
        assert line.sim.servo(1).eeprom.speed == (90 if how == "write" else 127)


@pytest.mark.parametrize("how", ["write", "restore"])
def test_a_verified_write_whose_read_after_met_a_lost_port_is_not_told_to_try_again(
    browser: Browser, tmp_path: Path, how: str
) -> None:
    # The adapter pulled out just after a write was verified, as the page read the servo again: once the line was
    # back the page said "the line is back: try again", which invited a second write of one already done.
    line = PtyLine((1,))
    with web_server_page(browser, line) as p:
        button, result = write_or_restore_shown(p, line, tmp_path, how)

        def unplugged_first(route: Any) -> None:  # (the server's read then meets the lost port itself)
            line.sim.unplug()
            route.continue_()

        p.route("**/api/servo/1/eeprom", unplugged_first)
        p.click(button)
        expect(p.locator(result)).to_contain_text("written and verified by reading it back")
        expect(p.locator("#lost-banner")).to_be_visible()
        p.unroute("**/api/servo/1/eeprom")
        line.sim.replug()
        expect(p.locator("#message")).to_contain_text("the line is back")
        expect(p.locator("#message")).not_to_contain_text("try again")
        expect(p.locator("#message")).to_contain_text("was verified")
        assert line.sim.servo(1).eeprom.speed == (90 if how == "write" else 127)


def test_an_action_after_a_read_that_failed_says_that_servo_was_not_read(browser: Browser) -> None:
    # Read of ID 9 (absent) after servo 1's page: every button then said "read a servo first", Read just pressed.
    line = PtyLine((1,))
    with web_server_page(browser, line) as p:
        open_servo_page(p, 1)
        p.fill("#servo-id", "9")
        p.click("#servo-load")
        expect(p.locator("#message")).to_contain_text("did not answer")
        p.click("#plan-btn")
        expect(p.locator("#message")).to_have_text(
            "no servo is shown: the read of servo 9 failed; read a servo that answers first"
        )


def test_a_number_box_holding_what_is_no_number_is_said_so_not_empty(browser: Browser) -> None:
    # "--5" typed in the speed box, on show there: the page said "give speed a value", as of an empty box.
    line = PtyLine((1,))
    with web_server_page(browser, line) as p:
        open_servo_page(p, 1)
        box = p.locator("#eeprom-table [name=speed]")
        box.fill("")
        box.press_sequentially("--5")
        p.click("#plan-btn")
        expect(p.locator("#message")).to_contain_text("speed: not a number")
        expect(p.locator("#diff")).to_be_empty()
        assert line.sim.servo(1).eeprom.speed == 127


def test_an_eeprom_write_whose_port_was_lost_as_it_went_says_it_may_have_reached_the_servo(browser: Browser) -> None:
    # The port went as the servo heard the write (it took it): the page said only "port lost", then, the line back
    # and Write pressed again, "EEPROM changed since the diff": nothing told whether the write had reached it.
    line = PtyLine(())
    puller = UnplugsWhenAsked(1, WriteEeprom)
    line.sim.add_device(puller)
    with web_server_page(browser, line) as p:
        open_servo_page(p, 1)
        puller.line = line.sim
        p.fill("#eeprom-table [name=speed]", "90")
        p.click("#plan-btn")
        p.click("#write-btn")
        expect(p.locator("#lost-banner")).to_be_visible()
        expect(p.locator("#message")).to_contain_text("the write may have reached servo 1")
        expect(p.locator("#message")).to_contain_text("read it once the line is back")
        expect(p.locator("#eeprom-table [name=speed]")).to_have_value("90")  # (the edit is still there to write)
        puller.line = None
        line.sim.replug()
        expect(p.locator("#lost-banner")).to_be_hidden()
        expect(p.locator("#message")).to_contain_text("the line is back")
        expect(p.locator("#message")).to_contain_text("read servo 1")  # (not "try again": the write may be done)
        p.click("#write-btn")  # pressed again all the same: refused, pointing at the read
        expect(p.locator("#message")).to_contain_text("changed since the diff was shown")
        expect(p.locator("#message")).to_contain_text("press Read")
        p.click("#servo-load")
        servo_read(p, 1)
        expect(p.locator("#eeprom-table [name=speed]")).to_have_value("90")  # the edit kept through the read
        p.click("#plan-btn")
        expect(p.locator("#diff")).to_contain_text("the servo already has these values")  # it had reached it
        assert puller.eeprom.speed == 90


def test_a_jog_the_server_never_answered_says_so_not_that_its_answer_was_lost(browser: Browser) -> None:
    # With the server gone (stopped, its network down), the jog's target showed "not confirmed" and its title said
    # the jog "was sent but its answer was lost", though it may never have left the browser.
    with held_by_its_page(browser, 8000) as (_, servo, p):
        p.route("**/api/servo/1/move", lambda route: route.abort())  # the request fails as with no server
        p.click("#jog-plus")
        expect(p.locator("#message")).to_contain_text("the configurator's server does not answer")
        expect(p.locator("#jog-target")).to_have_text("8100? (not confirmed)")  # it may have reached the server
        expect(p.locator("#jog-target")).to_have_attribute("title", re.compile("the server did not answer"))
        expect(p.locator("#jog-target")).not_to_have_attribute("title", re.compile("was sent"))
        assert servo.target == 8000
        p.unroute("**/api/servo/1/move")


def test_motion_a_closed_tab_switched_on_goes_off_on_the_server_and_a_jog_is_refused(browser: Browser) -> None:
    line = PtyLine((1,))
    servo = line.sim.servo(1)
    servo.move_by_hand(8000)
    with web_server_page(browser, line) as p:
        open_servo_page(p, 1)
        p.check("#motion-switch")
        # (the servo holds once the command is on the wire; motion is on once its answer came: the page's jog says so)
        expect(p.locator("#jog-plus")).to_be_enabled()
        assert servo.target == 8000
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
    expect(p.locator("#jog-plus")).to_be_enabled()  # (motion on: the server's answer came)
    assert not servo.free
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
        until_on(p, lambda: len(held) == 1, "enable motion was never asked")
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


def test_the_live_plot_says_a_servo_held_after_a_lost_port_and_why(browser: Browser) -> None:
    # The stream sends a servo it held nothing once the port is back (it may have restarted, free and
    # elsewhere): plotted as if plain, its line just went flat; the terminal says "waiting for a target".
    line = PtyLine((1,))
    with web_server_page(browser, line) as p:
        start_live_plot(p, "1")
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


def apply_punch_to_many(p: Page, ids: str, punch: int) -> None:
    """On the Many servos page: ``punch`` for the servos ``ids`` (as the page's field takes them), applied."""
    p.goto(p.url.split("#")[0] + "#many")
    p.fill("#many-ids", ids)
    p.check("[name=use-punch]")
    p.fill("[name=value-punch]", str(punch))
    p.click("#many-apply")


def test_the_many_servos_page_says_one_failure_once_naming_its_servos_in_words(browser: Browser) -> None:
    # Each absent ID had a row of the library's words with the bytes sent ("read_eeprom to ID 5: no reply
    # ... (raw: a5 00)"), the same news once per servo.
    line = PtyLine((1,))
    with web_server_page(browser, line) as p:
        apply_punch_to_many(p, "1,5,6", 3)
        expect(p.locator("#many-results tbody tr")).to_have_count(3)
        expect(p.locator("#many-results tr[data-id='1']")).to_contain_text("verified")
        expect(p.locator("#many-errors li")).to_have_count(1)
        expect(p.locator("#many-errors li")).to_contain_text(re.compile(r"^servos 5, 6: no reply at 115,200 baud"))
        expect(p.locator("#many-results tr[data-id='6']")).to_contain_text("failed (see above)")
        assert "raw" not in (p.locator("#page-many").text_content() or "")
        assert line.sim.servo(1).eeprom.punch == 3


def test_the_many_servos_page_shows_each_fields_range(browser: Browser) -> None:
    # The Servo page showed "1..127" beside speed; the Many servos page showed no range for any field, so a value
    # out of range was found only by pressing Apply.
    line = PtyLine((1,))
    with web_server_page(browser, line) as p:
        p.goto(p.url.split("#")[0] + "#many")
        speed = p.locator("#many-fields tr[data-field='speed']")
        expect(speed.locator("td.range")).to_have_text("1..127")
        expect(speed.locator("input[type=number]")).to_have_attribute("max", "127")
        expect(p.locator("#many-fields tr[data-field='stretch_gain'] td.range")).to_have_text("2..254 even")


def test_the_many_servos_page_shows_the_last_applys_outcome_after_a_reload(browser: Browser) -> None:
    # The page reloaded as Apply ran: the servos were written, the page said nothing of it.
    line = PtyLine((1,))
    with web_server_page(browser, line) as p:
        apply_punch_to_many(p, "1,5", 3)
        expect(p.locator("#many-results tr[data-id='1']")).to_contain_text("verified")
        p.reload()
        p.goto(p.url.split("#")[0] + "#many")
        expect(p.locator("#many-last")).to_have_text("the last Apply (servos 1, 5), from this page or another:")
        expect(p.locator("#many-results tr[data-id='1']")).to_contain_text("written, verified")
        expect(p.locator("#many-errors li")).to_have_count(1)
        assert line.sim.servo(1).eeprom.punch == 3


def test_the_many_servos_page_says_a_write_taken_but_not_read_back_is_written_not_verified(browser: Browser) -> None:
    # Servo 2's cable pulled as it acknowledged the write: its row said "failed" of a servo that took it.
    line = PtyLine((1,))
    gone = UnpluggedAfterWrite(2)
    line.sim.add_device(gone)
    gone.line = line.sim
    with web_server_page(browser, line) as p:
        apply_punch_to_many(p, "1,2", 3)
        expect(p.locator("#many-results tr[data-id='2']")).to_contain_text("written, not verified")
        expect(p.locator("#many-errors li")).to_have_text(
            re.compile(r"^servo 2: acknowledged the EEPROM write, then did not answer its read-back")
        )
        expect(p.locator("#many-results tr[data-id='1']")).to_contain_text("written, verified")
        assert gone.eeprom.punch == 3


def test_the_many_servos_page_says_a_write_cut_short_as_it_went_may_be_written(browser: Browser) -> None:
    # The port lost as servo 2's write went out (or servo 1's write left unanswered): the words above said the write
    # may have reached it, its row "failed (see above)".
    line = PtyLine((3,))
    line.sim.add_device(TakesTheWriteSilently(1))
    puller = UnplugsWhenAsked(2, WriteEeprom)
    line.sim.add_device(puller)
    puller.line = line.sim
    with web_server_page(browser, line) as p:
        apply_punch_to_many(p, "1-3", 3)
        expect(p.locator("#many-results tr[data-id='2']")).to_contain_text(
            "may be written (port lost as it went): read it"
        )
        expect(p.locator("#many-results tr[data-id='1']")).to_contain_text("may be written (no answer): read it")
        expect(p.locator("#many-results tr[data-id='3']")).to_contain_text("not tried")
        said = p.locator("#many-errors li").nth(1)
        expect(said).to_have_text(re.compile(r"^servo 2: .*the write may have reached it; read it once the line"))
        assert puller.eeprom.punch == 3


def backed_up_many(p: Page, folder: Path) -> Path:
    """The Many servos page's **Back up all**, its download saved in ``folder`` under the name it was offered."""
    with p.expect_download() as download:
        p.click("#many-backup")
    backup = folder / download.value.suggested_filename
    download.value.save_as(backup)
    return backup


def test_back_up_all_saves_the_servos_found_in_one_file_that_a_servo_page_restores_from(
    browser: Browser, tmp_path: Path
) -> None:
    line = PtyLine((1, 2, 3, 4))
    for i in (1, 2, 3):
        line.sim.servo(i).eeprom = line.sim.servo(i).eeprom.replace(speed=10 * i)
    sim = line.sim
    with web_server_page(browser, line) as p:
        scan_finds(p, 3, ids="0-3")
        p.click("a[href='#many']")
        expect(p.locator("#many-ids")).to_have_value("1,2,3")  # the servos the scan found, as the page lists them
        backup = backed_up_many(p, tmp_path)
        assert backup.name == "servos-01-03.json"
        held = backups_in(json.loads(backup.read_text()))
        assert {i: doc["fields"]["speed"] for i, doc in held.servos.items()} == {1: 10, 2: 20, 3: 30}
        expect(p.locator("#message")).to_have_text("3 servo(s) saved as servos-01-03.json")
        expect(p.locator("#many-backup-missing li")).to_have_count(0)
        # Servo 2's page restores servo 2 from the file of three: its own backup, not the first in the file.
        sim.servo(2).eeprom = sim.servo(2).eeprom.replace(speed=99)
        open_servo_page(p, 2)
        p.set_input_files("#restore-file", str(backup))
        expect(p.locator("#restore-diff tr.changed")).to_contain_text("20")
        # (which backup of the three: said, as a one-servo file's note says whose it is)
        expect(p.locator("#restore-diff")).to_contain_text(
            "servos-01-03.json holds the backups of servos 1-3: servo 2's is restored"
        )
        p.click("#restore-btn")
        expect(p.locator("#restore-result")).to_contain_text("verified")
        expect(p.locator("#message")).to_have_text("servo 2: restored and verified")  # (as a write says it on top)
        assert sim.servo(2).eeprom.speed == 20 and sim.servo(1).eeprom_writes == sim.servo(3).eeprom_writes == 0
        # Servo 4's page: the file has none of it, and says which servos it holds (the file named, as it was chosen).
        open_servo_page(p, 4)
        p.set_input_files("#restore-file", str(backup))
        expect(p.locator("#message")).to_have_text(
            "servos-01-03.json: the file holds the backups of servos 1-3, none of servo 4"
        )
        expect(p.locator("#restore-btn")).to_be_disabled()
        assert sim.servo(4).eeprom_writes == 0


def test_back_up_all_keeps_what_it_read_when_a_servo_is_silent_and_the_port_is_lost_and_names_the_rest(
    browser: Browser, tmp_path: Path
) -> None:
    line = PtyLine((1, 4))
    puller = UnplugsWhenAsked(3, ReadEeprom)  # (its cable pulled as its EEPROM is asked for)
    line.sim.add_device(puller)
    puller.line = line.sim
    with web_server_page(browser, line) as p:
        p.goto(p.url.split("#")[0] + "#many")
        p.fill("#many-ids", "1,2,3,4")
        backup = backed_up_many(p, tmp_path)
        held = backups_in(json.loads(backup.read_text()))
        assert list(held.servos) == [1] and sorted(held.not_saved) == [2, 3, 4], held
        expect(p.locator("#message")).to_have_text(
            "1 servo(s) saved as servos-01-04.json; not saved: servos 2, 3, 4 (see below)"
        )
        said = p.locator("#many-backup-missing li")
        expect(said).to_have_count(2)  # (the servos the port was lost at and after: one cause, said once)
        expect(said.nth(0)).to_have_text(re.compile(r"^servo 2: no reply at 115,200 baud: check its power"))
        expect(said.nth(1)).to_have_text(
            "servos 3, 4: not read: the port was lost at servo 3; back it up again once the port is back"
        )
        expect(p.locator("#lost-banner")).to_be_visible()
        line.sim.replug()
        expect(p.locator("#lost-banner")).to_be_hidden()


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
        start_live_plot(p, "1,2")
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
        expect(p.locator("#message")).to_have_text(
            "no servo is shown: the read of servo 1 failed; read a servo that answers first"
        )
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
        # (the RAM read after the write shown: ended after the fill below, it put the box back to 60, and on a loaded
        # machine the next write sent 60)
        expect(p.locator("#ram-table tr", has_text="speed")).to_contain_text("60")
        assert servo.speed == 60 and servo.stretch == 30
        # A refused write leaves no earlier success beside it ("speed = 60 in RAM" stood beside the refusal).
        p.fill("#ram-value", "500")
        p.click("#ram-write")
        expect(p.locator("#message")).to_contain_text("speed")
        expect(p.locator("#ram-result")).to_have_text("")
        assert servo.speed == 60


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
        expect(p.locator("#message")).to_have_text(refused("stretch"))  # (it said "give the RAM value a value")
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


@pytest.mark.parametrize("restarted", [False, True], ids=["stopped", "started-again-with-another-token"])
def test_the_servo_page_of_a_server_gone_shows_motion_off_and_no_position_as_read_now(
    browser: Browser, restarted: bool
) -> None:
    # Ctrl-C (or a restart, with a new token this page cannot use) with a servo's page open: its "enable motion"
    # stayed ticked, its jog buttons live, and its last position "read now", under the words that the server was
    # gone.  The server that comes back knows no motion switched on: a jog there is refused.
    line = PtyLine((1,), ics36=(1,))
    with socket.socket() as probe:  # a free port, for both servers: the page comes back to the same address
        probe.bind(("127.0.0.1", 0))
        listen = f"127.0.0.1:{probe.getsockname()[1]}"
    environment = {k: v for k, v in os.environ.items() if k not in ("ICS35_PORT", "ICS35_WEB_TOKEN")}

    def start() -> subprocess.Popen[str]:
        command = [*WEB, "--port", line.path, "--listen", listen, *PATIENT_OPTION]
        return subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, env=environment)

    first = start()
    second: subprocess.Popen[str] | None = None

    def restarted_first(route: Route) -> None:
        # The page asks the server's status once its socket closes: the new server answers it, as it does when
        # the restart is quicker than the page.
        nonlocal second
        if first.poll() is not None and second is None:
            second = start()
            assert second.stdout is not None
            second.stdout.readline()  # (its address printed: it listens)
        route.continue_()

    context = browser.new_context()
    try:
        assert first.stdout is not None
        p = context.new_page()
        p.goto(first.stdout.readline().strip())
        if restarted:
            p.route("**/api/status", restarted_first)
        open_servo_page(p, 1)
        p.check("#motion-switch")
        expect(p.locator("#jog-plus")).to_be_enabled()
        expect(p.locator("#jog-position-note")).to_contain_text("read now")
        first.terminate()
        first.wait(10)
        gone = "server started again: open its new address" if restarted else "server gone"
        expect(p.locator("#line-status")).to_have_text(gone)
        expect(p.locator("#motion-switch")).not_to_be_checked()
        for control in ("#jog-minus", "#jog-slider", "#jog-plus"):
            expect(p.locator(control)).to_be_disabled()
        expect(p.locator("#jog-position")).to_have_text("-")
        expect(p.locator("#jog-position-note")).to_contain_text("not read now: the configurator's server")
    finally:
        context.close()
        stop_servers(first, second)
        line.close()


def test_an_edit_typed_on_a_servos_page_and_not_written_is_still_there_back_on_its_page(browser: Browser) -> None:
    # Typed, then a look at another page: back through the Servo link the page still showed the edit but every
    # button said "read a servo first", and Read (as did the browser's Back, to #servo/1) read it again over the edit.
    line = PtyLine((1, 2))
    with web_server_page(browser, line) as p:
        open_servo_page(p, 1)
        p.fill("#eeprom-table [name=speed]", "70")
        p.click("nav a[href='#line']")
        p.click("nav a[href='#servo']")
        servo_read(p, 1)
        expect(p.locator("#eeprom-table [name=speed]")).to_have_value("70")
        p.click("#plan-btn")
        expect(p.locator("#diff tr.changed")).to_have_text(re.compile(r"speed\s*127\s*70"))
        p.fill("#eeprom-table [name=punch]", "9")
        p.click("nav a[href='#live']")
        p.go_back()
        servo_read(p, 1)
        expect(p.locator("#eeprom-table [name=punch]")).to_have_value("9")
        expect(p.locator("#eeprom-table [name=speed]")).to_have_value("70")
        p.click("#plan-btn")
        expect(p.locator("#diff tr.changed")).to_have_count(2)
        p.click("#write-btn")
        expect(p.locator("#write-result")).to_contain_text("verified")
        assert line.sim.servo(1).eeprom.speed == 70 and line.sim.servo(2).eeprom.speed == 127
        open_servo_page(p, 2)  # another servo's page reads that servo: nothing of servo 1's stays
        expect(p.locator("#eeprom-table [name=speed]")).to_have_value("127")
        # Back on servo 2's page after the Many servos page wrote to it: read again, its new value shown (not the
        # one read before, as if read now), with what was typed kept.
        p.fill("#eeprom-table [name=punch]", "7")
        p.click("nav a[href='#many']")
        p.fill("#many-ids", "2")
        p.check("[name=use-dead_band]")
        p.fill("[name=value-dead_band]", "4")
        p.click("#many-apply")
        expect(p.locator("#many-results tr[data-id='2']")).to_contain_text("verified")
        p.go_back()
        servo_read(p, 2)
        expect(p.locator("#eeprom-table [name=dead_band]")).to_have_value("4")
        expect(p.locator("#eeprom-table [name=punch]")).to_have_value("7")

        def back_while_unplugged() -> None:  # through the Servo link, servo 2's cable out: the read fails
            p.click("nav a[href='#line']")
            unplugged = line.sim.remove_servo(2)
            p.click("nav a[href='#servo']")
            expect(p.locator("#message")).to_contain_text("ID 2")
            line.sim.add_device(unplugged)

        # Back while its cable is out: the read fails, and the next one (Read, once it is back) keeps the edit.
        back_while_unplugged()
        p.click("#servo-load")
        servo_read(p, 2)
        expect(p.locator("#eeprom-table [name=punch]")).to_have_value("7")
        # So does coming back once more through the Servo link: the page came back empty, nothing read, the edit
        # back only at Read.
        back_while_unplugged()
        p.click("nav a[href='#line']")
        p.click("nav a[href='#servo']")
        servo_read(p, 2)
        expect(p.locator("#eeprom-table [name=punch]")).to_have_value("7")


def test_an_edit_typed_after_show_changes_is_not_written_unshown(browser: Browser) -> None:
    # Show changes, then one more box changed: Write and verify wrote both, the second never in a diff.
    line = PtyLine((1,))
    with web_server_page(browser, line) as p:
        open_servo_page(p, 1)
        p.fill("#eeprom-table [name=speed]", "70")
        p.click("#plan-btn")
        expect(p.locator("#write-btn")).to_be_enabled()
        p.fill("#eeprom-table [name=punch]", "9")
        expect(p.locator("#write-btn")).to_be_disabled()
        expect(p.locator("#diff")).to_contain_text("Show changes again")
        p.click("#plan-btn")
        expect(p.locator("#diff tr.changed")).to_have_count(2)
        p.click("#write-btn")
        expect(p.locator("#write-result")).to_contain_text("verified")
        assert (line.sim.servo(1).eeprom.speed, line.sim.servo(1).eeprom.punch) == (70, 9)


def test_a_write_that_switches_motion_off_says_so(browser: Browser) -> None:
    # Jogging, then a speed written to the EEPROM: the page reads the servo again after the write, which switches
    # its motion off; the switch went off with nothing said, the next jog's button dead.
    with held_by_its_page(browser, 8000) as (_, servo, p):
        p.fill("#eeprom-table [name=speed]", "70")
        p.click("#plan-btn")
        p.click("#write-btn")
        expect(p.locator("#write-result")).to_contain_text("verified")
        expect(p.locator("#motion-switch")).not_to_be_checked()
        expect(p.locator("#message")).to_contain_text("written and verified")
        expect(p.locator("#message")).to_contain_text("motion is off")
        assert servo.target == 8000 and not servo.free  # (it keeps holding)
