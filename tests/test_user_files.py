"""A person's files: read as text by one rule (the robot file, motions, start poses, backups, recordings)."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from ics35_async import InvalidArgument
from ics35_async.robot import DescriptionError, MotionError, load_description, load_motion
from ics35_async.sim import TransactionRecorder, load_recording
from ics35_async.user_files import UnreadableText, decode_user_text, read_user_text


@pytest.mark.parametrize(
    ("raw", "said"),
    [
        (b"a\nb\nc\xe9\n", "byte 0xe9 on line 3"),
        (b"\xef\xbb\xbfa\nb\nc\xe9\n", "byte 0xe9 on line 3"),  # (after a byte order mark: the byte, not the mark's)
        (b"\xef\xbb\xbfx\xe9\n", "byte 0xe9 on line 1"),
    ],
)
def test_text_that_is_not_utf8_names_its_first_bad_byte_and_line(raw: bytes, said: str) -> None:
    with pytest.raises(UnreadableText, match=said):
        decode_user_text(raw, "a motion is UTF-8 JSON")


def test_a_byte_order_mark_is_read_past() -> None:
    assert decode_user_text(b"\xef\xbb\xbf{}\n", "x") == "{}\n"


def test_an_empty_path_is_named_empty_by_every_reader(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # (a script's unset variable: pathlib reads "" as ".", and the readers said ". is a directory" or raised a bare
    # IsADirectoryError)
    monkeypatch.chdir(tmp_path)
    with pytest.raises(UnreadableText, match="empty"):
        read_user_text("", "x")
    with pytest.raises(MotionError, match="empty"):
        load_motion("")
    with pytest.raises(DescriptionError, match="empty"):
        load_description("")
    with pytest.raises(InvalidArgument, match="empty"):
        load_recording("")
    with pytest.raises(InvalidArgument, match="empty"):
        TransactionRecorder("")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.skipif(sys.platform == "win32", reason="a pseudo-terminal stands for the serial port")
@pytest.mark.parametrize(
    ("program", "said", "words"),
    [
        # (where a robot file goes, a port is said to be one, and where the port goes instead)
        ("from ics35_async.robot import load_description as load", "DescriptionError", "looks like a port (a device)"),
        ("from ics35_async.robot import load_motion as load", "MotionError", "not a file"),
        ("from ics35_async.blocking import open_robot as load", "DescriptionError", "looks like a port (a device)"),
    ],
)
def test_a_serial_port_given_for_a_file_is_refused_not_read_for_ever(program: str, said: str, words: str) -> None:
    """``open_robot("/dev/ttyUSB0")``, the port where the robot file goes, read the port as a file: a serial port
    has no end, so the program waited for ever, saying nothing (``/dev/zero`` filled the memory instead)."""
    master, slave = os.openpty()
    port = os.ttyname(slave)
    try:
        code = textwrap.dedent(
            f"""
            {program}
            try:
                load({port!r})
            except Exception as exc:
                print(type(exc).__name__, exc)
            """
        )
        done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=30)
    except subprocess.TimeoutExpired:
        pytest.fail("still reading the serial port after 30 s")
    finally:
        os.close(slave)
        os.close(master)
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith(f"{said} {port}: ") and words in done.stdout, done.stdout
