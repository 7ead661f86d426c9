"""Servos plugged into, unplugged from and power-cycled on a simulated line while it runs (the library's
side of ``ics35 sim --console``; the console itself is tested on a pty in test_sim_console.py)."""

from __future__ import annotations

import threading

import pytest

from ics35_async.eeprom import BaudRate
from ics35_async.sim import VirtualLine, VirtualServo


def h(text: str) -> bytes:
    return bytes.fromhex(text)


def answers(line: VirtualLine, servo_id: int) -> bytes:
    """What a stretch read of ``servo_id`` brings back after its 2-byte echo (b"": silence)."""
    received = b"".join(chunk for _, chunk in line.process(bytes([0xA0 | servo_id, 0x01])))
    return received[2:]


def test_a_removed_servo_answers_no_more_and_the_others_still_do() -> None:
    line = VirtualLine([1, 2, 3])
    assert answers(line, 2) == h("22 01 1E")
    removed = line.remove_servo(2)
    assert removed.servo_id == 2
    assert [s.servo_id for s in line.servos] == [1, 3]
    assert answers(line, 2) == b""
    assert answers(line, 3) == h("23 01 1E")
    with pytest.raises(KeyError, match="no servo with ID 2"):
        line.remove_servo(2)
    assert [s.servo_id for s in line.servos] == [1, 3]


def test_of_two_servos_at_one_id_the_one_plugged_in_last_leaves() -> None:
    first = VirtualServo(0)
    line = VirtualLine([first])
    second = VirtualServo(0)
    line.add_device(second)
    assert line.servos_at(0) == [first, second]
    assert answers(line, 0) != h("20 01 1E")  # two replies at once: garbled
    assert line.remove_servo(0) is second
    assert line.servos_at(0) == [first]
    assert answers(line, 0) == h("20 01 1E")


def test_remove_device_takes_that_object_and_refuses_one_not_on_the_line() -> None:
    line = VirtualLine([1], memory={5: b"x"})
    memory = line.memory_device(5)
    line.remove_device(memory)
    assert line.devices == line.servos
    with pytest.raises(ValueError, match="not on this simulated line"):
        line.remove_device(memory)
    with pytest.raises(ValueError, match="not on this simulated line"):
        line.remove_device(VirtualServo(1))  # another servo at the same ID is not this one
    assert len(line.servos) == 1


def test_a_new_baud_rate_takes_effect_at_power_cycle_of_that_servo_only() -> None:
    line = VirtualLine([1, 2])
    for servo in line.servos:
        servo.eeprom = servo.eeprom.replace(baud_rate=BaudRate.B1250000)
    assert answers(line, 1) == h("21 01 1E")  # still at 115200 until powered off and on
    assert line.power_cycle(1) == [line.servo(1)]
    assert answers(line, 1) == b""
    assert answers(line, 2) == h("22 01 1E")
    line.baudrate = 1250000
    assert answers(line, 1) == h("21 01 1E")
    assert answers(line, 2) == b""
    assert [s.power_cycles for s in line.servos] == [1, 0]


def test_power_cycle_of_an_absent_id_changes_nothing() -> None:
    line = VirtualLine([1])
    with pytest.raises(KeyError, match="no servo with ID 4"):
        line.power_cycle(4)
    assert line.servo(1).power_cycles == 0
    assert line.power_cycle() == line.servos
    assert line.servo(1).power_cycles == 1


def test_servo_states_say_what_each_listens_at_and_what_its_eeprom_holds() -> None:
    line = VirtualLine([1, 2], ics36=[2])
    line.servo(1).eeprom = line.servo(1).eeprom.replace(baud_rate=BaudRate.B625000)
    line.servo(2).move_by_hand(9000)
    states = line.servo_states()
    assert [(s.servo_id, s.eeprom_baud, s.baud, s.ics36, s.position, s.free) for s in states] == [
        (1, 625000, 115200, False, 7500, True),
        (2, 115200, 115200, True, 9000, True),
    ]


def test_plugging_and_unplugging_while_another_thread_talks_to_the_line() -> None:
    line = VirtualLine([1])
    stop = threading.Event()
    heard: list[bytes] = []

    def talk() -> None:
        while not stop.is_set():
            heard.append(answers(line, 1))

    talker = threading.Thread(target=talk)
    talker.start()
    try:
        for _ in range(200):
            line.add_device(VirtualServo(2))
            line.power_cycle(2)
            line.remove_servo(2)
    finally:
        stop.set()
        talker.join()
    assert heard and set(heard) == {h("21 01 1E")}
    assert [s.servo_id for s in line.servos] == [1]
