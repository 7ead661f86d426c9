"""ics35 sniff and its decoder (protocol.listening): a line heard once, commands and replies in one stream.

The bytes come from the simulator's tap (every byte on its wire, once), so
the expected transactions are the simulator's own log, not a hand-written copy.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import click
import pytest

from ics35_async.eeprom import Eeprom
from ics35_async.protocol import Position, ReadEeprom, ReadId, ReadMemory, ReadParam, WriteEeprom, WriteParam
from ics35_async.protocol.listening import HeardTransaction, LineListener
from ics35_async.sim import VirtualLine, load_recording, serving
from tests.support.timing import PATIENT_OPTION

PAUSE = 0.02  # between transactions, as a controller leaves (longer than the listener's 5 ms gap)


def hear(line: VirtualLine, commands: list[bytes], baudrate: int = 115200) -> list[HeardTransaction]:
    """Send ``commands`` to ``line`` one by one; decode what its tap heard, PAUSE apart."""
    heard: list[bytes] = []
    line.add_tap(heard.append)
    listener = LineListener(baudrate)
    decoded: list[HeardTransaction] = []
    for n, tx in enumerate(commands):
        before = len(heard)
        line.process(tx)
        for chunk in heard[before:]:
            decoded += listener.feed(chunk, n * PAUSE)
    return decoded + listener.flush()


def test_every_kind_of_transaction_is_decoded_as_the_line_logged_it() -> None:
    commands = [
        Position(1, 7500, baudrate=115200).tx,
        Position(2, 0, baudrate=115200).tx,  # free
        ReadParam(1, 4).tx,
        ReadParam(3, 1).tx,
        WriteParam(2, 2, 100).tx,
        ReadEeprom(2).tx,
        ReadParam(9, 4).tx,  # nobody answers
        ReadMemory(20, 0, 4).tx,
    ]
    with VirtualLine([1, 2, 3], memory={20: b"\x01\x02\x03\x04"}, log_size=None) as line:
        commands.append(WriteEeprom(2, line.servo(2).eeprom).tx)
        decoded = hear(line, commands)
        log = list(line.log)
    assert len(decoded) == len(log) == len(commands)
    for heard, logged in zip(decoded, log, strict=True):
        assert (heard.kind, heard.servo_id, heard.sent, heard.reply) == (
            logged.command,
            logged.servo_id,
            logged.tx,
            logged.reply,
        )
        if logged.reply:
            assert heard.error is None and heard.value == logged.value
        else:
            assert heard.error == "no reply" and heard.value is None
    assert decoded[0].to_dict()["value"] == 7500
    assert isinstance(decoded[5].value, Eeprom) and decoded[5].to_dict()["value"]["servo_id"] == 2
    assert decoded[7].to_dict()["value"] == "01020304"


def test_replies_that_keep_their_top_bit_are_told_from_commands() -> None:
    # ID 0's position reply at 115200 starts 0x80 (ICS 2.0 compatibility); the ID reply is 0xE0|id.
    with VirtualLine([0], log_size=None) as line:
        decoded = hear(
            line, [Position(0, 7500, baudrate=115200).tx, ReadId().tx, Position(0, 7000, baudrate=115200).tx]
        )
    assert [(h.kind, h.reply[:1], h.error) for h in decoded] == [
        ("position", b"\x80", None),
        ("read_id", b"\xe0", None),
        ("position", b"\x80", None),
    ]
    assert decoded[1].value == 0


def test_a_command_with_the_same_first_byte_after_a_pause_is_a_new_command() -> None:
    listener = LineListener(115200)
    tx = Position(0, 7500, baudrate=115200).tx
    decoded = listener.feed(tx, 0.0) + listener.feed(tx, 0.030) + listener.flush()
    assert [(h.kind, h.sent, h.reply, h.error) for h in decoded] == [
        ("position", tx, b"", "no reply"),
        ("position", tx, b"", "no reply"),
    ]


def test_garbled_and_unknown_bytes_are_reported_and_sync_comes_back() -> None:
    listener = LineListener(115200)
    read = ReadParam(1, 4).tx
    stream = [
        (b"\x05\x06\x07", 0.0),  # stray data bytes
        (read + b"\x21\x04\x50", 0.02),
        (read + b"\x21\x04", 0.04),  # the reply is cut short by the next command
        (read + b"\x21\x05\x50", 0.041),  # wrong sub-command in the reply
        (b"\xa1\x09", 0.06),  # a read of a sub-command the codec does not know
        (read + b"\x21\x04\x33", 0.08),
    ]
    decoded = [h for data, t in stream for h in listener.feed(data, t)] + listener.flush()
    summary = [(h.kind, h.error is None) for h in decoded]
    assert summary == [
        ("unknown", False),
        ("read_temperature", True),
        ("read_temperature", False),
        ("read_temperature", False),
        ("unknown", False),
        ("read_temperature", True),
    ]
    assert decoded[2].error == "reply cut off" and decoded[2].reply == b"\x21\x04"
    assert "SC" in (decoded[3].error or "")
    assert decoded[-1].value == 0x33


def test_a_reply_that_never_comes_is_closed_by_the_silence() -> None:
    listener = LineListener(115200, gap=0.005)
    assert listener.feed(ReadParam(1, 4).tx, 1.0) == []
    assert listener.poll(1.004) == []  # the reply may still come
    (closed,) = listener.poll(1.010)
    assert closed.error == "no reply" and closed.t == 1.0


# ----------------------------------------------------------------------------- the command, through a tap


@pytest.mark.skipif(not hasattr(os, "openpty"), reason="the tap is a pty (POSIX)")
def test_sniff_json_decodes_every_transaction_another_program_sent(tmp_path: Path) -> None:
    tap = tmp_path / "tap"
    recording = tmp_path / "line.txt"
    out_file = tmp_path / "sniffed.jsonl"
    with serving(["--ids", "1-3", "--tap", str(tap), "--record", str(recording)]) as port:
        sniffer = subprocess.Popen(
            [sys.executable, "-m", "ics35_async.cli", "sniff", "--port", str(tap), "--json",
             "--output", str(out_file), "--duration", "60"],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )  # fmt: skip
        try:
            assert sniffer.stderr is not None
            assert "listening on" in sniffer.stderr.readline()  # the port is open: nothing sent from now is lost
            env = {**os.environ, "ICS35_PORT": port}
            # Every reply expected (a pty server on a loaded machine answers late): the patient allowance.
            for args in (["info", "2", "--no-position"], ["get", "3", "temperature"], ["free", "1"]):
                done = subprocess.run(
                    [sys.executable, "-m", "ics35_async.cli", *PATIENT_OPTION, *args],
                    env=env,
                    capture_output=True,
                    text=True,
                    timeout=60,
                )
                assert done.returncode == 0, done.stderr
            time.sleep(0.3)
        finally:
            sniffer.send_signal(2)  # Ctrl-C: sniff's normal end
            stdout, stderr = sniffer.communicate(timeout=20)
    assert sniffer.returncode == 0, stderr
    assert "Traceback" not in stderr and "transactions heard" in stderr
    lines = [json.loads(x) for x in stdout.splitlines()]
    assert [json.loads(x) for x in out_file.read_text().splitlines()] == lines
    entries = load_recording(recording)
    assert entries and len(lines) == len(entries)
    for got, entry in zip(lines, entries, strict=True):
        assert bytes.fromhex(got["sent"]) == entry.tx
        assert bytes.fromhex(got["reply"]) == entry.rx[len(entry.tx) :]  # what the host heard after its echo
        assert got["kind"] == entry.comment.split()[1] and got["error"] is None
        assert set(got) >= {"t", "kind", "id", "sent", "reply", "value"}
    assert [g["kind"] for g in lines][-1] == "free" and lines[-1]["id"] == 1


def test_sniff_refuses_the_simulator(cli: Any) -> None:
    result = cli("sniff")
    assert result.code == 2 and "listening adapter's --port" in result.err and "--tap" in result.err


def test_the_text_line_names_the_value_or_why_there_is_none() -> None:
    from ics35_async.cli._sniff import text_line

    with VirtualLine([2], log_size=None) as line:
        eeprom, temperature, absent = hear(line, [ReadEeprom(2).tx, ReadParam(2, 4).tx, ReadParam(9, 4).tx])
    assert "read_eeprom" in text_line(eeprom) and "= EEPROM id 2, 115200 baud, stretch 60" in text_line(eeprom)
    assert text_line(temperature).split()[1:4] == ["id", "2", "read_temperature"]
    assert "! no reply" in text_line(absent) and text_line(absent).endswith("a9 04 | -")


@pytest.mark.parametrize(("count", "heard"), [(1, "1 transaction heard"), (2, "2 transactions heard")])
def test_sniff_count_stops_at_that_many_transactions(tmp_path: Path, count: int, heard: str) -> None:
    """``--count N`` prints N transactions, also when more were decoded at once: here four commands written
    in one go, so their transactions reach the listener together."""
    tap = tmp_path / "tap"
    with serving(["--ids", "1-3", "--tap", str(tap)]) as port:
        sniffer = subprocess.Popen(
            [sys.executable, "-m", "ics35_async.cli", "sniff", "--port", str(tap), "--json", "--count", str(count)],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        try:
            assert sniffer.stderr is not None
            assert "listening on" in sniffer.stderr.readline()
            fd = os.open(port, os.O_RDWR | os.O_NOCTTY)
            try:
                os.write(fd, b"".join(ReadParam(servo_id, 2).tx for servo_id in (1, 2, 3, 1)))
                stdout, stderr = sniffer.communicate(timeout=20)
            finally:
                os.close(fd)
        finally:
            if sniffer.poll() is None:
                sniffer.send_signal(2)
                sniffer.communicate(timeout=20)
    assert sniffer.returncode == 0, stderr
    assert [json.loads(line)["id"] for line in stdout.splitlines()] == [1, 2][:count], stdout
    assert f"count reached: {heard} (" in stderr


def test_the_json_options_help_names_every_key_a_line_carries() -> None:
    from ics35_async.cli._sniff import sniff

    with VirtualLine([2], log_size=None) as line:
        (heard,) = hear(line, [ReadParam(2, 4).tx])
    (option,) = [p for p in sniff.params if isinstance(p, click.Option) and p.name == "as_json"]
    named = re.search(r"\(([^)]*)\)", option.help or "")
    assert named is not None and named.group(1).split(", ") == list(heard.to_dict()), option.help
