"""Recording a session and replaying it as a scripted device."""

from __future__ import annotations

import io
from pathlib import Path

import pytest

from ics35_async.eeprom import Eeprom
from ics35_async.errors import InvalidArgument
from ics35_async.protocol import Position, ReadEeprom, ReadParam, WriteEeprom, WriteParam
from ics35_async.sim import ReplayDevice, VirtualLine, load_recording, parse_recording


class Host:
    def __init__(self) -> None:
        self.data = bytearray()

    def deliver(self, data: bytes) -> None:
        self.data += data

    def lost(self, exc: Exception | None) -> None:
        pass


def script() -> list[bytes]:
    return [
        Position(1, 7500, baudrate=115200).tx,
        ReadParam(2, 1).tx,
        WriteParam(2, 2, 60).tx,
        ReadEeprom(1).tx,
        WriteEeprom(1, Eeprom.factory(1).replace(speed=99)).tx,
        bytes.fromhex("A1 06"),  # unknown sub-command
        Position(3, 9000, baudrate=115200).tx,
        bytes.fromhex("FF 00 00 00"),  # garbled: three servos
        Position(1, 0, baudrate=115200).tx,
    ] * 3


def run(device: VirtualLine | ReplayDevice, commands: list[bytes]) -> list[bytes]:
    host = Host()
    device.connect(host, 115200)
    received = []
    for command in commands:
        device.write(command)
        received.append(bytes(host.data))
        host.data.clear()
    device.disconnect()
    return received


def test_record_format_is_one_readable_line_per_transaction() -> None:
    stream = io.StringIO()
    bus = VirtualLine([1], record=stream)
    run(bus, [Position(1, 7500, baudrate=115200).tx, bytes.fromhex("A1 06")])
    bus.stop_recording()
    lines = stream.getvalue().splitlines()
    assert lines[0].startswith("# ics35 sim recording")
    stamp, rest = lines[1].split(" ", 1)
    assert float(stamp) > 0
    assert rest.startswith("81 3a 4c -> 81 3a 4c | 01 3a 4c  # id=1 position value=7500")
    assert " a1 06 -> a1 06  # id=1 unknown" in lines[2]
    assert len(lines) == 3


def test_replay_reproduces_a_recorded_session_with_faults(tmp_path: Path) -> None:
    path = tmp_path / "session.txt"
    commands = script()
    bus = VirtualLine([1, 2, 3], faults="drop:0.1,late:0.1,corrupt:0.1,noise:0.1", seed=4, record=path)
    live = run(bus, commands)
    bus.close()
    assert len(load_recording(path)) == len(commands)

    replay = ReplayDevice(path)
    assert run(replay, commands) == live
    assert replay.mismatches == [] and replay.remaining == 0


def test_replay_reports_a_host_that_deviates() -> None:
    recording = [
        "# ics35 sim recording v1",
        "0.1 81 3a 4c -> 81 3a 4c | 01 3a 4c",
        "0.2 a1 01 -> a1 01 | 21 01 1e",
    ]
    replay = ReplayDevice(recording)
    received = run(replay, [bytes.fromhex("81 3a 4c"), bytes.fromhex("a1 02"), bytes.fromhex("a1 01")])
    assert received == [bytes.fromhex("81 3a 4c 01 3a 4c"), b"", bytes.fromhex("a1 01 21 01 1e")]
    assert len(replay.mismatches) == 1
    assert replay.mismatches[0].expected == bytes.fromhex("a1 01")
    assert replay.mismatches[0].got == bytes.fromhex("a1 02")
    run(replay, [bytes.fromhex("81 3a 4c")])
    assert replay.mismatches[-1].expected == b""  # nothing left to replay


def test_replay_reassembles_split_writes() -> None:
    replay = ReplayDevice(["0 81 3a 4c -> 81 3a 4c | 01 3a 4c"])
    received = run(replay, [bytes.fromhex("81"), bytes.fromhex("3a 4c")])
    assert received == [b"", bytes.fromhex("81 3a 4c 01 3a 4c")]


def test_parse_recording_accepts_comments_blank_lines_and_silence() -> None:
    entries = parse_recording(["", "  # just a comment", "1.5 83 3a 4c -> -  # nobody home", "2 81 00 -> 81 00"])
    assert [(e.time, e.tx, e.rx) for e in entries] == [
        (1.5, bytes.fromhex("83 3a 4c"), b""),
        (2.0, bytes.fromhex("81 00"), bytes.fromhex("81 00")),
    ]
    assert entries[0].comment == "nobody home"


@pytest.mark.parametrize("line", ["81 3a 4c", "x 81 -> 81", "0.1 -> 81", "0.1 8g -> 81", "0.1 81 -> zz"])
def test_parse_recording_rejects_bad_lines(line: str) -> None:
    with pytest.raises(InvalidArgument):
        parse_recording([line])


@pytest.mark.parametrize(
    ("raw", "phrase"),
    [
        (b"\x7fELF\x02\x01\x01\x00\x00\xd0\xd1", "not a text file"),
        (b"0.000 81 3A 4C -> 81 3A 4C 01 3A 4C  # caf\xe9\n", "not UTF-8 text: byte 0xe9 on line 1"),
    ],
    ids=["binary", "latin-1"],
)
def test_a_recording_that_is_not_utf8_text_is_named_so(tmp_path: Path, raw: bytes, phrase: str) -> None:
    # A binary file given by mistake as --replay (or sim://?replay=): a UnicodeDecodeError traceback.
    given = tmp_path / "session.bin"
    given.write_bytes(raw)
    with pytest.raises(InvalidArgument, match=phrase) as caught:
        load_recording(given)
    assert str(given) in str(caught.value)


def test_a_recording_saved_with_a_byte_order_mark_replays(tmp_path: Path) -> None:
    given = tmp_path / "session.txt"
    given.write_bytes(b"\xef\xbb\xbf0.000 81 3A 4C -> 81 3A 4C 01 3A 4C\r\n")
    assert [entry.tx for entry in load_recording(given)] == [bytes.fromhex("81 3A 4C")]
