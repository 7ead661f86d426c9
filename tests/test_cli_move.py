"""``move`` keeps a servo inside its travel: counts beyond it need --force, small counts suggest --deg."""

from __future__ import annotations

from typing import Any

import pytest

from ics35_async import units
from ics35_async.cli import ExitCode
from ics35_async.sim import VirtualServo


def positions_sent(sim: Any) -> list[int]:
    """The targets of the position commands the line saw (from their bytes: 0x80|ID, high 7 bits, low 7 bits)."""
    return [(t.tx[1] << 7) | t.tx[2] for t in sim.log_since(0) if t.command == "position"]


def test_a_small_count_suggests_degrees_and_sends_nothing(cli: Any, sim_line: Any) -> None:
    sim, url = sim_line([1])
    result = cli("--port", url, "move", "1", "90")
    assert result.code == ExitCode.USAGE
    assert f"ics35 --port {url} move 1 90 --deg" in result.err and "3500..11500" in result.err
    assert sim.transactions == 0


def test_the_degrees_hint_is_the_same_command_line_with_its_line_options(cli: Any, sim_line: Any) -> None:
    """Run as given, the hint must reach the same line: without --port it would refuse (or read the simulator)."""
    sim, url = sim_line([1])
    result = cli("--port", url, "move", "1", "90", "--timeout", "0.05", "--no-echo")
    assert result.code == ExitCode.USAGE
    hint = " ".join(result.err.split())
    assert f"ics35 --port {url} --timeout 0.05 --no-echo move 1 90 --deg" in hint, result.err
    assert sim.transactions == 0


def test_a_negative_count_suggests_degrees(cli: Any, sim_line: Any) -> None:
    sim, url = sim_line([1])
    result = cli("--port", url, "move", "1", "-30")
    assert result.code == ExitCode.USAGE
    assert "--deg" in result.err
    assert sim.transactions == 0


@pytest.mark.parametrize("degrees", ["200", "-135.5", "1000"])
def test_degrees_beyond_135_are_refused(cli: Any, sim_line: Any, degrees: str) -> None:
    sim, url = sim_line([1])
    result = cli("--port", url, "move", "1", degrees, "--deg")
    assert result.code == ExitCode.USAGE
    assert "135" in result.err
    assert sim.transactions == 0


@pytest.mark.parametrize("counts", ["3499", "11501", "16000"])
def test_counts_beyond_the_travel_need_force(cli: Any, sim_line: Any, counts: str) -> None:
    sim, url = sim_line([1])
    result = cli("--port", url, "move", "1", counts)
    assert result.code == ExitCode.USAGE
    assert "--force" in result.err
    assert sim.transactions == 0
    result = cli("--port", url, "move", "1", counts, "--force", "--json")
    assert result.code == 0, result.err
    assert positions_sent(sim) == [int(counts)]


def test_the_servos_eeprom_pulse_limits_are_kept(cli: Any, sim_line: Any) -> None:
    servo = VirtualServo(1)
    servo.eeprom = servo.eeprom.replace(pulse_limit_low=5000, pulse_limit_high=10000)
    sim, url = sim_line([servo])
    for args in (["4000"], ["10001"], ["-90", "--deg"]):
        result = cli("--port", url, "move", "1", *args)
        assert result.code == ExitCode.REFUSED, args
        assert "5000..10000" in result.err and "--force" in result.err
    assert positions_sent(sim) == []
    assert cli("--port", url, "move", "1", "-80", "--deg").code == 0  # 5130 counts
    assert cli("--port", url, "move", "1", "4000", "--force").code == 0
    assert positions_sent(sim) == [units.degrees_to_position(-80), 4000]


def test_the_edges_of_the_travel_are_allowed(cli: Any, sim_line: Any) -> None:
    sim, url = sim_line([1])
    for args in (["3500"], ["11500"], ["-135", "--deg"], ["135", "--deg"]):
        assert cli("--port", url, "move", "1", *args).code == 0, args
    assert positions_sent(sim) == [3500, 11500, 3500, 11500]
