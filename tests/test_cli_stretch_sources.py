"""Where each command's stretch comes from: scan and info show the EEPROM's stretch_gain (loaded at power-up, twice the
RAM scale), get the servo's RAM stretch in use now.  A newcomer saw "stretch 60" in scan and info and "stretch = 30"
in get, with nothing saying why."""

from __future__ import annotations

from typing import Any

import pytest

from tests.support.terminal import screen_of, typed_on_a_terminal


def test_scan_info_and_get_each_say_where_their_stretch_comes_from(cli: Any, sim_line: Any) -> None:
    sim, url = sim_line([1])
    eeprom_gain, ram_stretch = sim.servo(1).eeprom.stretch_gain, sim.servo(1).stretch
    assert eeprom_gain != ram_stretch  # (the two numbers the newcomer saw)

    scanned = cli("--port", url, "scan", "--bauds", "115200", "--ids", "1")
    assert scanned.code == 0, scanned.err
    heading = next(line for line in scanned.out.splitlines() if line.split()[:1] == ["ID"])
    assert "stretch_gain" in heading.split(), heading  # the EEPROM field's own name, not the RAM parameter's
    assert "EEPROM" in scanned.out.split("\n ID")[0], scanned.out  # the title says whose settings these are

    info = cli("--port", url, "info", "1", "--no-position")
    assert info.code == 0, info.err
    said = " ".join(info.out.split())
    assert "EEPROM (loaded into RAM at power-up" in said, said
    assert f"stretch_gain │ {eeprom_gain} │" in said, said

    got = cli("--port", url, "get", "1", "stretch")
    assert got.code == 0, got.err
    said = " ".join(got.out.split())
    assert f"servo 1 stretch = {ram_stretch} (RAM, now;" in said, said
    assert "stretch_gain" in said and "EEPROM" in said, said  # names the other number and where it is


@pytest.mark.parametrize("columns", [50, 100])
def test_the_scan_table_keeps_every_value_whole_on_a_terminal(columns: int) -> None:
    # At 50 columns rich cut every column's values: "115…" for a baud rate, "35…" for a pulse range.
    args = ["--port", "sim://stretch-sources?ids=1-2", "scan", "--bauds", "115200"]
    code, written = typed_on_a_terminal(args, [], columns=columns)
    screen = [line for line in screen_of(written, width=columns) if line.strip()]
    said = "\n".join(screen)
    assert code == 0 and "Traceback" not in written, said
    assert "…" not in said, said
    rows = [line.split() for line in screen if line.split()[:2] in (["1", "115200"], ["2", "115200"])]
    assert len(rows) == 2, said
    assert all(row[2] == "60" and row[3] == "127" for row in rows), said  # stretch_gain, speed
    if columns >= 100:
        assert all("3500-11500" in row for row in rows), said
    else:
        assert "columns left out:" in said, said


@pytest.mark.parametrize("quick", [[], ["--quick"]])
def test_the_scan_table_into_a_log_keeps_every_value_whole(cli: Any, sim_line: Any, quick: list[str]) -> None:
    # Into a log (a pipe, a file) the table is drawn at its own width: --quick's table, with its empty note
    # column, came out with its rates cut ("1152…").
    _, url = sim_line([1, 2])
    result = cli("--port", url, "scan", "--bauds", "115200", "--ids", "0-3", *quick)
    assert result.code == 0, result.err
    said = [line.split() for line in result.out.splitlines()]
    rows = [words for words in said if words[:1] in (["1"], ["2"]) and "servo(s)" not in words]
    assert [row[:2] for row in rows] == [["1", "115200"], ["2", "115200"]], result.out
    assert "…" not in result.out, result.out
