"""Sharper messages where a device half-answers: the EEPROM read unanswered by a servo that answers short
reads, an ID-0 position reply wrong in its top bit alone, and a device that answers scan's ID read only."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ics35_async.sim import VirtualServo


def test_a_servo_that_answers_short_reads_but_not_the_eeprom_read_is_told_so(sim_line: Any, cli: Any) -> None:
    _, url = sim_line([VirtualServo(2, ignores={"read_eeprom"}), 3])
    result = cli("--port", url, "info", "2", "--no-position")
    assert result.code == 4
    assert "servo 2 answers short reads" in result.err and "but not the EEPROM read" in result.err
    assert "66 bytes" in result.err
    absent = cli("--port", url, "info", "7", "--no-position")  # nobody there: the usual message
    assert absent.code == 4 and "servo 7 did not answer" in absent.err and "short reads" not in absent.err


def recording(tmp_path: Path, reply: str, times: int = 4) -> str:
    lines = ["# ics35 sim recording v1"] + [f"0.00{n} 80 00 00 -> 80 00 00 | {reply}" for n in range(times)]
    path = tmp_path / "line.txt"
    path.write_text("\n".join(lines) + "\n")
    return f"sim://?replay={path}"


def test_an_id0_reply_wrong_in_its_top_bit_alone_names_the_ics20_rule(tmp_path: Path, cli: Any) -> None:
    # At 115200 servo 0's position reply keeps its top bit (0x80); this device clears it.
    result = cli("--port", recording(tmp_path, "00 3a 4c"), "free", "0")
    assert result.code == 1
    assert "only the top bit differs" in result.err and "ICS 2.0 compatibility" in result.err
    assert "ID other than 0" in result.err


def test_other_garbled_id0_replies_keep_the_general_hint(tmp_path: Path, cli: Any) -> None:
    result = cli("--port", recording(tmp_path, "05 3a 4c"), "free", "0")
    assert result.code == 1
    assert "top bit" not in result.err and "a garbled reply" in result.err


def test_scan_names_a_device_that_answers_the_id_read_but_no_stretch_read(sim_line: Any, cli: Any) -> None:
    _, url = sim_line([VirtualServo(3, ignores={"read_stretch"})])
    result = cli("--port", url, "scan", "--bauds", "115200")
    assert result.code == 4
    assert "answered the ID read (as ID 3) but no stretch read" in result.err
    data = cli("--port", url, "scan", "--bauds", "115200", "--json")
    assert data.code == 4 and data.json()["id_read_only"] == [{"baud": 115200, "id": 3}]
    _, fine = sim_line([3])
    assert "ID read" not in cli("--port", fine, "scan", "--bauds", "115200").err
