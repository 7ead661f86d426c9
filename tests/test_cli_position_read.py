"""info and monitor leave the torque alone: no position or free command to an ICS 3.5 servo unless --free,
ICS 3.6 positions through the position read; read back from the simulator's log."""

from __future__ import annotations

import json
from typing import Any

from ics35_async.sim import VirtualLine, VirtualServo

TORQUE_COMMANDS = {"position", "free"}


def sent(sim: VirtualLine, servo_id: int) -> list[str]:
    return [t.command for t in sim.log_since(0) if t.servo_id == servo_id]


def test_info_sends_an_ics35_servo_no_position_or_free_command(cli: Any, sim_line: Any) -> None:
    sim, url = sim_line([1])
    assert cli("--port", url, "move", "1", "8000").code == 0
    seq = sim.transactions
    result = cli("--port", url, "info", "1")
    assert result.code == 0, result.err
    assert "ICS 3.5" in result.out and "not read" in result.out and "--free" in result.out
    assert not TORQUE_COMMANDS & {t.command for t in sim.log_since(seq)}
    assert sim.servo(1).target == 8000  # still holding
    doc = cli("--port", url, "info", "1", "--json").json()
    assert doc["position"] is None and doc["free"] is False and doc["protocol"] == "ICS 3.5"
    assert "free command" in doc["no_position_because"]
    assert not TORQUE_COMMANDS & {t.command for t in sim.log_since(seq)}


def test_info_shows_an_ics36_servos_position_without_freeing_it(cli: Any, sim_line: Any) -> None:
    sim, url = sim_line([VirtualServo(1, position=9000, ics36=True)])
    result = cli("--port", url, "info", "1", "--json")
    assert result.code == 0, result.err
    doc = result.json()
    assert (doc["position"], doc["position_read_by"], doc["free"]) == (9000, "read", False)
    assert doc["protocol"] == "ICS 3.6" and doc["no_position_because"] is None
    assert not TORQUE_COMMANDS & set(sent(sim, 1))
    assert "torque left as it was" in cli("--port", url, "info", "1").out
    assert not TORQUE_COMMANDS & set(sent(sim, 1))


def test_info_free_reads_an_ics35_servo_by_freeing_it_and_says_so(cli: Any, sim_line: Any) -> None:
    sim, url = sim_line([VirtualServo(1, position=8200)])
    result = cli("--port", url, "info", "1", "--free")
    assert result.code == 0, result.err
    assert "8200" in result.out and "torque now OFF" in result.out
    assert sent(sim, 1).count("free") == 1
    assert cli("--port", url, "info", "1", "--free", "--no-position").code == 2


def test_monitor_watches_ics36_servos_and_names_the_ics35_ones_without_touching_either(cli: Any, sim_line: Any) -> None:
    sim, url = sim_line([VirtualServo(1), VirtualServo(2, position=9000, ics36=True), VirtualServo(3)])
    sim.servo(2).command_position(9000)  # holding: a joint of a standing robot
    result = cli("--port", url, "--timeout", "0.005", "monitor", "1-3", "--seconds", "0.3", "--json")
    assert result.code == 0, result.err
    final = [json.loads(ln) for ln in result.out.splitlines()][-1]["servos"]
    assert final["2"]["position"] == 9000 and final["2"]["no_position_because"] is None
    for sid in ("1", "3"):
        assert final[sid]["position"] is None and "free command" in final[sid]["no_position_because"]
        assert final[sid]["temperature"] is not None or final[sid]["current"] is not None  # still watched
    for sid in (1, 2, 3):
        assert not TORQUE_COMMANDS & set(sent(sim, sid)), sid
    assert sim.servo(2).target == 9000  # still holding


def test_monitor_refuses_when_every_servo_would_have_to_go_limp(cli: Any, sim_line: Any) -> None:
    sim, url = sim_line([1, 2])
    result = cli("--port", url, "monitor", "1,2", "--seconds", "0.3")
    assert result.code == 5, result.err
    assert "ICS 3.5" in result.err and "--free" in result.err
    assert not TORQUE_COMMANDS & {t.command for t in sim.log_since(0)}


def test_monitor_free_frees_only_the_ics35_servos(cli: Any, sim_line: Any) -> None:
    sim, url = sim_line([VirtualServo(1, position=8000), VirtualServo(2, ics36=True)])
    sim.servo(2).command_position(7000)
    result = cli("--port", url, "--timeout", "0.005", "monitor", "1,2", "--free", "--seconds", "0.3", "--json")
    assert result.code == 0, result.err
    final = [json.loads(ln) for ln in result.out.splitlines()][-1]["servos"]
    assert final["1"]["position"] == 8000
    assert "free" in sent(sim, 1) and sim.servo(1).free
    assert not TORQUE_COMMANDS & set(sent(sim, 2)) and sim.servo(2).target == 7000


def test_monitor_free_does_not_free_an_ics36_servo_whose_replies_are_lost(cli: Any, sim_line: Any) -> None:
    # Holding, every reply lost (a lossy line, or late past the probes' short wait): its protocol cannot be told.
    # --free is for ICS 3.5 servos; the free command reaches a servo whose reply is lost, and it went limp.
    sim, url = sim_line([VirtualServo(1, position=8000), VirtualServo(2, ics36=True)], faults="drop@2:1.0")
    sim.servo(2).command_position(7000)
    # (1 s: silent to the plan's probes, servo 2 is offline from the stream's start, probed every 0.5 s)
    result = cli("--port", url, "--timeout", "0.005", "monitor", "1,2", "--free", "--seconds", "1", "--json")
    assert result.code == 0, result.err
    assert "free" in sent(sim, 1) and sim.servo(1).free  # the ICS 3.5 servo, as asked
    assert not TORQUE_COMMANDS & set(sent(sim, 2)) and sim.servo(2).target == 7000
    assert sent(sim, 2).count("read_position") >= 2  # watched (its probe is the read), not left out


def test_monitor_json_says_what_the_current_and_temperature_readings_mean(cli: Any, sim_line: Any) -> None:
    # The table shows the temperature in about °C and the current with its sign; the JSON line gave the raw
    # parameters alone (127 for a servo at about 42 °C, 70 for a reverse current of 6), which a log read as
    # a servo at 127 °C drawing 70.  It gives them as `ics35 get` and `info` do: raw beside what they mean.
    sim, url = sim_line([VirtualServo(1, ics36=True, load=-5, ambient_celsius=60.0)])
    sim.servo(1).temperature_celsius = 60.0
    sim.servo(1).command_position(7500)  # holding against a reverse load: a reverse current
    result = cli("--port", url, "--timeout", "0.005", "monitor", "1", "--seconds", "0.3", "--json")
    assert result.code == 0, result.err
    seen = [json.loads(ln) for ln in result.out.splitlines()][-1]["servos"]["1"]
    current, temperature = seen["current"], seen["temperature"]
    assert current == {"raw": sim.servo(1).current_raw, "magnitude": sim.servo(1).current, "reverse": True}, seen
    assert temperature["raw"] == sim.servo(1).temperature, seen
    assert abs(temperature["celsius_approx"] - sim.servo(1).temperature_celsius) < 5, seen
