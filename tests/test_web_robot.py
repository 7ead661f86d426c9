"""The Robot page's API (``ics35 web --robot``): joints by name, motion only when switched on, limits,
a motion played and stopped, the safety state; checked on the simulated servos."""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import json
import os
import time
import warnings
from collections.abc import Iterator, Mapping
from pathlib import Path
from types import MappingProxyType, SimpleNamespace
from typing import Any

import pytest
from starlette.testclient import TestClient

from ics35_async import InvalidArgument, UnsafeOperation, sim
from ics35_async.robot import RobotWarning
from ics35_async.robot.profiles import LONGEST_MOTION, check_duration
from ics35_async.sim import VirtualServo
from ics35_async.units import degrees_to_position
from ics35_async.web import LineConfig, LineSession, create_app
from ics35_async.web.api import updates
from ics35_async.web.joints import RobotSession
from ics35_async.web.security import COOKIE
from tests.support.pty_line import PtyLine

TOKEN = "robot-test-token-0123456789"
BASE = "http://127.0.0.1:8766"
JSON = {"content-type": "application/json"}
_names = itertools.count()


def arm_file(tmp_path: Path, name: str, more: str = "") -> Path:
    """A two-joint arm on the simulated line ``sim://NAME`` (servos 1 and 2); ``more``: tables added to it."""
    path = tmp_path / "arm.toml"
    path.write_text(
        f"""name = "arm"
[lines.arm]
port = "sim://{name}?ids=1-2"
rate_hz = 200
[joints.shoulder]
line = "arm"
id = 1
min = -30
max = 60
[joints.elbow]
line = "arm"
id = 2
min = 0
max = 90
"""
        + more
    )
    return path


@contextlib.contextmanager
def robot_page(path: Path, name: str, *lines: str) -> Iterator[TestClient]:
    """The configurator serving the robot file ``path`` (the pages' own line on ``sim://NAME-config``), signed in;
    the simulated lines named ``lines`` closed after, whatever the test did."""
    app = create_app(LineSession(LineConfig(port=f"sim://{name}-config")), TOKEN, robot=RobotSession(str(path)))
    try:
        with TestClient(app, base_url=BASE) as client:
            client.cookies.set(COOKIE, TOKEN)
            yield client
    finally:
        for line in lines:
            sim.named(line).close()


@contextlib.contextmanager
def arm_page(tmp_path: Path, more: str = "") -> Iterator[tuple[TestClient, Any]]:
    """The Robot page of a two-joint arm on a simulated line (see arm_file): the client and the simulated line."""
    name = f"web-robot-{next(_names)}"
    with robot_page(arm_file(tmp_path, name, more), name, name) as client:
        yield client, sim.named(name)


FOUR_JOINTS = (
    '[joints.neck]\nline = "upper"\nid = 1\n[joints.arm]\nline = "upper"\nid = 2\n'
    '[joints.hip]\nline = "lower"\nid = 1\n[joints.knee]\nline = "lower"\nid = 2\n'
)


@contextlib.contextmanager
def two_line_page(
    tmp_path: Path, joints: str = FOUR_JOINTS, upper: str = "ids=1-2", lower: str = "ids=1-2"
) -> Iterator[tuple[TestClient, Any, Any]]:
    """The Robot page of a robot on two simulated lines, "upper" and "lower" (``upper``, ``lower``: their URLs'
    queries), with ``joints`` (a robot file's tables; by default two ICS 3.5 joints a line: upper neck 1, arm 2;
    lower hip 1, knee 2): the client and the two simulated lines."""
    name = f"web-robot-{next(_names)}"
    path = tmp_path / "two.toml"
    path.write_text(
        f'[lines.upper]\nport = "sim://{name}-upper?{upper}"\nrate_hz = 200\n'
        f'[lines.lower]\nport = "sim://{name}-lower?{lower}"\nrate_hz = 200\n' + joints
    )
    with robot_page(path, name, f"{name}-upper", f"{name}-lower") as client:
        yield client, sim.named(f"{name}-upper"), sim.named(f"{name}-lower")


@pytest.fixture
def robot(tmp_path: Path) -> Iterator[tuple[TestClient, Any]]:
    """A two-joint arm on a simulated line; yields the client and the simulated line."""
    with arm_page(tmp_path) as page:
        yield page


def post(client: TestClient, path: str, data: Any = None) -> Any:
    return client.post(path, content=json.dumps({} if data is None else data), headers=JSON)


def wait_for(check: Any, seconds: float = 10.0) -> None:
    end = time.monotonic() + seconds
    while not check():
        assert time.monotonic() < end, "the condition never came true"
        time.sleep(0.02)


def test_joints_move_only_with_motion_on_and_within_their_limits(robot: Any) -> None:
    client, line = robot
    view = client.get("/api/robot").json()
    assert [j["name"] for j in view["joints"]] == ["shoulder", "elbow"] and view["open"]
    refused = post(client, "/api/robot/move", {"pose": {"elbow": 45}})
    assert refused.status_code == 409 and "enable motion" in refused.json()["error"]
    assert line.servo(2).target is None
    assert post(client, "/api/robot/motion", {"enabled": True}).json()["motion_enabled"]
    outside = post(client, "/api/robot/move", {"pose": {"elbow": 120}})
    assert outside.status_code == 400 and "0..90" in outside.json()["error"]
    unknown = post(client, "/api/robot/move", {"pose": {"knee": 10}})
    assert unknown.status_code == 400 and "unknown joint" in unknown.json()["error"]
    start = line.servo(2).target
    assert post(client, "/api/robot/move", {"pose": {"elbow": 45}, "duration": 0.2}).status_code == 200
    wait_for(lambda: client.get("/api/robot").json()["joints"][1]["target"] == 45.0)
    assert line.servo(2).target != start
    post(client, "/api/robot/free")
    wait_for(lambda: line.servo(1).free and line.servo(2).free)
    assert client.get("/api/robot").json()["motion_enabled"] is False


def test_a_moves_time_is_held_to_the_librarys_rule_in_its_words(robot: Any) -> None:
    # The page's move had a rule of its own, 0..30 s: 0 threw the joint to its target at full speed (the library
    # refuses a keyframe at 0 s), and a move longer than 30 s was refused though the library plays up to an hour.
    client, line = robot
    assert post(client, "/api/robot/motion", {"enabled": True}).json()["motion_enabled"]
    wait_for(lambda: line.servo(2).target is not None)  # held where it stood
    held = line.servo(2).target
    for duration in (0, -1, 1e308, LONGEST_MOTION + 1, "1"):
        refused = post(client, "/api/robot/move", {"pose": {"elbow": 45}, "duration": duration})
        with pytest.raises(InvalidArgument) as rule:
            check_duration(duration)
        assert refused.status_code == 400 and refused.json()["error"] == str(rule.value), (duration, refused.text)
    assert line.servo(2).target == held  # nothing moved
    longer = post(client, "/api/robot/move", {"pose": {"elbow": 45}, "duration": 60})
    assert longer.status_code == 200, longer.text
    wait_for(lambda: line.servo(2).target != held)  # on its way, slowly
    post(client, "/api/robot/stop")


def test_enable_motion_leaves_a_free_joint_standing_past_its_limit_free_and_says_so(robot: Any) -> None:
    # Turned by hand to 120 degrees (the elbow's limit is 90), "enable motion" held it at 90: reached at full speed.
    client, line = robot
    line.servo(2).move_by_hand(degrees_to_position(120))
    wait_for(lambda: (client.get("/api/robot").json()["joints"][1]["position"] or 0) > 119)
    # A reading counts once the next one agrees (a jump of 120 degrees between two is a garbled reply to a
    # robot, unless confirmed; a simulated hand turns the servo there at once): a cycle later.
    seen = client.get("/api/robot").json()["cycle"]
    wait_for(lambda: client.get("/api/robot").json()["cycle"] > seen + 2)
    view = post(client, "/api/robot/motion", {"enabled": True}).json()
    assert "elbow left as it is: stands at 120.0 degrees, past its limit 90" in view["outcome"], view["outcome"]
    refused = post(client, "/api/robot/move", {"pose": {"elbow": 45}, "duration": 0.2})
    assert refused.status_code == 409 and "past its limit 90" in refused.json()["error"], refused.text
    # A motion naming it is refused too, as the request's answer (it was told only in the state line, once failed).
    motion = {"format": "ics35-motion", "version": 1, "keyframes": [{"time": 0.3, "pose": {"elbow": 45}}]}
    refused = post(client, "/api/robot/play", {"motion": motion})
    assert refused.status_code == 409 and "past its limit 90" in refused.json()["error"], refused.text
    wait_for(lambda: not line.servo(1).free)  # the shoulder holds
    assert line.servo(2).free


NOISY = 20  # reports: fewer than the 35 disagreeing readings in a row after which a wait gives a joint up


def test_enable_motion_holds_a_joint_whose_readings_settle_once_they_agree(robot: Any) -> None:
    # A joint posed by hand and held at once, its newest reading agreeing with none before it (turning fast, or a
    # garbled reply): "enable motion" left it free (to drop) with "hold it again once it settles".  It waits for
    # a reading that agrees, as a motion's start does, then holds it there.  (Readings that disagree stand in for
    # the turning hand: a noisy potentiometer's for a moment.)
    client, line = robot
    servo = line.servo(2)
    servo.move_by_hand(degrees_to_position(5))
    seen = client.get("/api/robot").json()["cycle"]
    wait_for(lambda: client.get("/api/robot").json()["cycle"] > seen + 2)  # (5 degrees read, and agreed)
    # The wiper settles after NOISY reports, counted by the servo itself: a timer (40 ms) let a loaded machine's
    # line run the 35 disagreeing readings after which the wait gives the joint up (a broken potentiometer) before
    # the noise ended.  The page is asked while the readings still disagree (a few reports in).
    left = [NOISY]
    reported = servo._reported

    def settling() -> int:
        left[0] -= 1
        if left[0] <= 0:
            servo.noisy = False
        return reported()

    servo._reported = settling
    servo.noisy = True
    wait_for(lambda: left[0] <= NOISY - 3)  # (its newest readings disagree)
    view = post(client, "/api/robot/motion", {"enabled": True}).json()
    assert left[0] <= 0, left  # (settled: enabling motion waited for it)
    assert view["outcome"] == "joints hold where they stand", view["outcome"]
    wait_for(lambda: not servo.free)
    assert servo.target == degrees_to_position(5)


def test_a_joint_freed_for_over_current_stays_stopped_until_reset_on_the_page(tmp_path: Path) -> None:
    # A free servo draws no current, so the trip cannot clear by itself: the page is the person's way to say
    # the cause is dealt with, as Robot.reset_trip is a program's.
    with arm_page(tmp_path, '[safety]\nmax_current = 20\naction = "free"\n') as (client, line):

        def elbow() -> Any:
            return client.get("/api/robot").json()["joints"][1]

        assert post(client, "/api/robot/motion", {"enabled": True}).status_code == 200
        line.servo(2).load = 40
        wait_for(lambda: elbow()["tripped"] is not None)
        wait_for(lambda: line.servo(2).free and elbow()["current"] == 0)  # read free: "within the limits"
        assert "draws current" in elbow()["tripped"]
        refused = post(client, "/api/robot/move", {"pose": {"elbow": 30}, "duration": 0.1})
        assert refused.status_code == 409 and "draws current" in refused.json()["error"], refused.text
        assert line.servo(2).free
        unknown = post(client, "/api/robot/reset_trip", {"joint": "knee"})
        assert unknown.status_code == 400 and "knee" in unknown.json()["error"]
        line.servo(2).load = 0
        reset = post(client, "/api/robot/reset_trip", {"joint": "elbow"})
        assert reset.status_code == 200 and reset.json()["joints"][1]["tripped"] is None
        assert "elbow" in reset.json()["outcome"]
        assert post(client, "/api/robot/move", {"pose": {"elbow": 30}, "duration": 0.1}).status_code == 200
        wait_for(lambda: not line.servo(2).free and line.servo(2).target == degrees_to_position(30))


def test_a_joint_freed_for_over_current_stays_stopped_across_a_reconnect_until_reset(tmp_path: Path) -> None:
    # A lost line and Reconnect opened a robot that knew nothing of the stop: the joint the watch had freed
    # for its load moved again at the next slider move, with no Reset, into the load that tripped it.
    with arm_page(tmp_path, '[safety]\nmax_current = 20\naction = "free"\n') as (client, line):

        def elbow() -> Any:
            return client.get("/api/robot").json()["joints"][1]

        post(client, "/api/robot/motion", {"enabled": True})
        line.servo(2).load = 40
        wait_for(lambda: elbow()["tripped"] is not None and line.servo(2).free)
        lose_and_replug(client, line)
        assert post(client, "/api/robot/reopen", {"lost_joints": "hold"}).json()["open"]
        assert "draws current" in (elbow()["tripped"] or ""), elbow()
        post(client, "/api/robot/motion", {"enabled": True})
        refused = post(client, "/api/robot/move", {"pose": {"elbow": 30}, "duration": 0.1})
        assert refused.status_code == 409 and "draws current" in refused.json()["error"], refused.text
        assert line.servo(2).free
        line.servo(2).load = 0
        assert post(client, "/api/robot/reset_trip", {"joint": "elbow"}).json()["joints"][1]["tripped"] is None
        assert post(client, "/api/robot/move", {"pose": {"elbow": 30}, "duration": 0.1}).status_code == 200
        wait_for(lambda: not line.servo(2).free)


def test_a_move_of_a_joint_whose_readings_never_agree_ends_in_one_line_on_the_page_and_moves_nothing(
    tmp_path: Path,
) -> None:
    # A servo with a broken potentiometer: its readings never agree, and a move waited for one that does, for ever.
    name = f"web-robot-{next(_names)}"
    path = arm_file(tmp_path, name)
    path.write_text(path.read_text().replace("?ids=1-2", "?ids=1-2&noisy=1"))
    with robot_page(path, name, name) as client:
        line = sim.named(name)
        view = post(client, "/api/robot/motion", {"enabled": True}).json()
        assert "shoulder left as it is" in view["outcome"], view["outcome"]
        assert post(client, "/api/robot/move", {"pose": {"shoulder": 45}, "duration": 0.2}).status_code == 200
        wait_for(lambda: client.get("/api/robot").json()["outcome"] is not None)
        outcome = client.get("/api/robot").json()["outcome"]
        assert outcome.startswith("move shoulder: joint shoulder (line arm, ID 1) last read at"), outcome
        assert "\n" not in outcome and "Traceback" not in outcome
        assert line.servo(1).free


def test_a_motion_plays_and_a_bad_one_is_refused_before_anything_moves(robot: Any) -> None:
    client, line = robot
    nod = [{"time": 0.3, "pose": {"shoulder": 20}}, {"time": 0.6, "pose": {"shoulder": 0}}]
    motion = {"format": "ics35-motion", "version": 1, "name": "nod", "keyframes": nod}
    assert post(client, "/api/robot/play", {"motion": motion}).status_code == 409  # motion not on
    post(client, "/api/robot/motion", {"enabled": True})
    wait_for(lambda: line.servo(1).target is not None)  # (the hold goes out with the line's next cycle)
    held = line.servo(1).target
    too_far = {**motion, "keyframes": [{"time": 0.3, "pose": {"shoulder": 99}}]}
    bad = post(client, "/api/robot/play", {"motion": too_far})
    assert bad.status_code == 400 and "shoulder" in bad.json()["error"]
    endless = {**motion, "keyframes": [{"time": 1e308, "pose": {"shoulder": 20}}]}
    bad = post(client, "/api/robot/play", {"motion": endless})
    assert bad.status_code == 400 and "keyframes[0].time: 1e+308 must be at most 3600" in bad.json()["error"], bad.text
    bad = post(client, "/api/robot/play", {"motion": motion, "speed": 0.01})  # (the library's rule: Robot.play's)
    assert bad.status_code == 400 and "speed must be in 0.05..10.0 times" in bad.json()["error"], bad.text
    slow = {**motion, "keyframes": [{"time": 200, "pose": {"shoulder": 20}}]}  # (4000 s at speed 0.05: over an hour)
    bad = post(client, "/api/robot/play", {"motion": slow, "speed": 0.05})
    assert bad.status_code == 400 and "at speed 0.05, keyframes[0].time: 4000" in bad.json()["error"], bad.text
    time.sleep(0.2)
    assert line.servo(1).target == held
    assert post(client, "/api/robot/play", {"motion": motion}).json()["playing"] == "nod"
    wait_for(lambda: client.get("/api/robot").json()["outcome"] == "nod: done")
    long = {**motion, "keyframes": [{"time": 5.0, "pose": {"shoulder": 50}}]}
    assert post(client, "/api/robot/play", {"motion": long}).json()["playing"]
    stopped = post(client, "/api/robot/stop").json()
    assert stopped["playing"] is None and stopped["outcome"].endswith("stopped")
    freed = post(client, "/api/robot/free").json()  # the page's state line then says so, not "stopped"
    assert freed["outcome"] == "joints free" and not freed["motion_enabled"], freed
    held = post(client, "/api/robot/motion", {"enabled": True}).json()  # and then, no longer "free"
    assert held["outcome"] == "joints hold where they stand" and held["motion_enabled"], held


def test_a_slider_moved_while_another_joints_move_runs_leaves_that_move_to_finish(robot: Any) -> None:
    # Two sliders moved one after the other within the move time: the second move stopped the first, and its
    # joint stayed where that stop left it, short of where its slider was put.
    client, line = robot
    post(client, "/api/robot/motion", {"enabled": True})
    wait_for(lambda: not line.servo(1).free and not line.servo(2).free)
    assert post(client, "/api/robot/move", {"pose": {"shoulder": 40}, "duration": 0.6}).status_code == 200
    assert post(client, "/api/robot/move", {"pose": {"elbow": 30}, "duration": 0.1}).status_code == 200
    goal = {1: degrees_to_position(40), 2: degrees_to_position(30)}
    wait_for(lambda: {1: line.servo(1).target, 2: line.servo(2).target} == goal)
    # Stop stops every move running, and Play (a motion of its own) takes over from them.
    post(client, "/api/robot/move", {"pose": {"shoulder": -20}, "duration": 5})
    post(client, "/api/robot/move", {"pose": {"elbow": 80}, "duration": 5})
    assert set(client.get("/api/robot").json()["playing"].split(", ")) == {"move shoulder", "move elbow"}
    stopped = post(client, "/api/robot/stop").json()
    assert stopped["playing"] is None, stopped
    time.sleep(0.4)  # (the smooth stop's ramp is over)
    held = {1: line.servo(1).target, 2: line.servo(2).target}
    time.sleep(0.3)
    far = {1: degrees_to_position(-20), 2: degrees_to_position(80)}
    assert {1: line.servo(1).target, 2: line.servo(2).target} == held and held[1] != far[1] and held[2] != far[2]


def test_switching_motion_off_stops_a_running_motion(robot: Any) -> None:
    # The switch reads as a safety switch: off must not leave a motion playing (it did, to its end).
    client, line = robot
    post(client, "/api/robot/motion", {"enabled": True})
    reach = [{"time": 5.0, "pose": {"shoulder": 50}}]
    long = {"format": "ics35-motion", "version": 1, "name": "reach", "keyframes": reach}
    assert post(client, "/api/robot/play", {"motion": long}).json()["playing"] == "reach"
    time.sleep(0.3)
    off = post(client, "/api/robot/motion", {"enabled": False}).json()
    assert off["playing"] is None and not off["motion_enabled"], off
    assert off["outcome"] == "reach: stopped (motion switched off)", off
    time.sleep(0.1)  # the smooth stop's ramp has ended (0.3 s at most, never past the motion's envelope)
    held = line.servo(1).target
    time.sleep(0.5)
    assert line.servo(1).target == held  # nothing moves it any more


WS = "ws://127.0.0.1:8766/ws"
# How the page's state line says motion went off because the page that switched it on went.
PAGE_GONE_SAID = "motion switched off: the page that switched it on was closed or lost its connection to the server"


def test_motion_a_page_switched_on_goes_off_when_its_socket_closes_and_a_motion_playing_stops_smoothly(
    robot: Any,
) -> None:
    # A closed tab left the robot's motion armed on the server: any later tab or script could move it.
    client, line = robot
    refused = post(client, "/api/robot/motion", {"enabled": True, "page": "p1"})  # (its socket not open)
    assert refused.status_code == 409 and "not connected" in refused.json()["error"], refused.json()
    no_name = post(client, "/api/robot/motion", {"enabled": True, "page": ["p1"]})  # (no page's name: refused too)
    assert no_name.status_code == 409 and "not connected" in no_name.json()["error"], no_name.text
    assert not client.get("/api/robot").json()["motion_enabled"]
    reach = [{"time": 5.0, "pose": {"shoulder": 50}}]
    long = {"format": "ics35-motion", "version": 1, "name": "reach", "keyframes": reach}
    with client.websocket_connect(f"{WS}?page=p1", headers={"origin": BASE}) as ws:
        ws.receive_json()
        assert post(client, "/api/robot/motion", {"enabled": True, "page": "p1"}).json()["motion_enabled"]
        with client.websocket_connect(f"{WS}?page=p2", headers={"origin": BASE}) as other:  # another tab
            other.receive_json()
        assert client.get("/api/robot").json()["motion_enabled"]  # (that tab switched nothing on)
        assert post(client, "/api/robot/play", {"motion": long}).json()["playing"] == "reach"
        time.sleep(0.3)
    wait_for(lambda: client.get("/api/robot").json()["playing"] is None)
    view = client.get("/api/robot").json()
    assert not view["motion_enabled"] and view["outcome"] == f"reach: stopped ({PAGE_GONE_SAID})", view
    moved = post(client, "/api/robot/move", {"pose": {"elbow": 45}})
    assert moved.status_code == 409 and "enable motion" in moved.json()["error"]
    # The smooth stop's ramp (0.3 s at most) goes on after the motion's end is said: once it is over, the
    # reach (10 degrees a second) moves the shoulder no further, and it keeps holding.
    held = line.servo(1).target
    end = time.monotonic() + 10.0
    while True:
        time.sleep(0.4)
        if line.servo(1).target == held:
            break
        assert time.monotonic() < end, "the shoulder kept moving after motion went off"
        held = line.servo(1).target
    time.sleep(0.5)
    assert line.servo(1).target == held and not line.servo(1).free


def test_the_robots_motion_is_the_last_page_to_switch_it_on_and_a_scripts_stays_on(robot: Any) -> None:
    client, _ = robot

    def on() -> bool:
        enabled: bool = client.get("/api/robot").json()["motion_enabled"]
        return enabled

    with client.websocket_connect(f"{WS}?page=b", headers={"origin": BASE}) as b:
        b.receive_json()
        with client.websocket_connect(f"{WS}?page=a", headers={"origin": BASE}) as a:
            a.receive_json()
            assert post(client, "/api/robot/motion", {"enabled": True, "page": "a"}).json()["motion_enabled"]
            assert post(client, "/api/robot/motion", {"enabled": True, "page": "b"}).json()["motion_enabled"]
        assert on()  # page b switched it on last: it is b's now
    wait_for(lambda: not on())
    assert client.get("/api/robot").json()["outcome"] == PAGE_GONE_SAID
    # A script names no page: its motion stays on until it switches it off, pages coming and going.
    assert post(client, "/api/robot/motion", {"enabled": True}).json()["motion_enabled"]
    with client.websocket_connect(f"{WS}?page=c", headers={"origin": BASE}) as c:
        c.receive_json()
        assert post(client, "/api/robot/motion", {"enabled": True, "page": "c"}).json()["motion_enabled"]
        assert post(client, "/api/robot/motion", {"enabled": True}).json()["motion_enabled"]  # the script's again
    time.sleep(0.3)
    assert on()
    assert not post(client, "/api/robot/motion", {"enabled": False}).json()["motion_enabled"]


def test_a_lost_line_is_told_and_the_robot_reopens_when_it_is_back(robot: Any) -> None:
    # The page said "open", no error, while every action failed with the lost port (until a restart).
    client, line = robot
    assert post(client, "/api/connect", {"robot_line": "arm"}).json()["connected"]  # the pages on its line too
    line.unplug()
    wait_for(lambda: client.get("/api/robot").json()["error"] is not None)
    view = client.get("/api/robot").json()
    assert not view["open"] and "lost" in view["error"], view
    refused = post(client, "/api/robot/motion", {"enabled": True})
    assert refused.status_code == 409 and "lost" in refused.json()["error"], refused.json()
    # The other pages, on its line, said only "not connected": they say why, and where the way back is.
    status = client.get("/api/status").json()
    assert not status["connected"] and "Reconnect" in (status["error"] or ""), status
    line.replug()
    reopened = post(client, "/api/robot/reopen")
    assert reopened.status_code == 200 and reopened.json()["open"] and reopened.json()["error"] is None, reopened.json()
    assert post(client, "/api/robot/motion", {"enabled": True}).json()["motion_enabled"]
    # The pages working on the robot's line follow it to the reopened robot (they kept the closed bus).
    status = client.get("/api/status").json()
    assert status["robot_line"] == "arm" and status["connected"], status


def test_reconnect_holding_the_lost_joints_says_which_did_not_answer(robot: Any) -> None:
    # "shoulder, elbow hold their last targets", where the elbow's servo was silent at Reconnect.
    client, line = robot
    post(client, "/api/robot/motion", {"enabled": True})
    assert post(client, "/api/robot/move", {"pose": {"shoulder": 10, "elbow": 20}, "duration": 0.1}).status_code == 200
    wait_for(lambda: line.servo(2).target == degrees_to_position(20))
    line.unplug()
    wait_for(lambda: client.get("/api/robot").json()["error"] is not None)
    elbow = line.remove_servo(2)
    line.replug()
    said = post(client, "/api/robot/reopen", {"lost_joints": "hold"}).json()["outcome"]
    assert said == "reconnected; shoulder holds its last target; elbow not answering yet", said
    elbow.command_position(degrees_to_position(50))  # (elsewhere meanwhile)
    line.add_device(elbow)

    # Back before the stream took it for offline (3 silent cycles): its last target reaches it.  Back after (a
    # loaded machine's test thread is that slow): it is held where it stands, sent nothing, and the page says so.
    # Either way nothing else is sent to it.
    def held() -> Any:
        return next(j for j in client.get("/api/robot").json()["joints"] if j["name"] == "elbow")["held"]

    wait_for(lambda: elbow.target == degrees_to_position(20) or held() == "rejoined")
    assert elbow.target in (degrees_to_position(20), degrees_to_position(50)) and not elbow.free


def test_a_line_lost_again_does_not_leave_the_last_reconnects_words_on_the_state_line(robot: Any) -> None:
    # "reconnected; ..." stayed on the state line through the next loss, beside the error that said it was lost.
    client, line = robot
    line.unplug()
    wait_for(lambda: client.get("/api/robot").json()["error"] is not None)
    line.replug()
    assert post(client, "/api/robot/reopen").json()["outcome"].startswith("reconnected")
    line.unplug()
    wait_for(lambda: client.get("/api/robot").json()["error"] is not None)
    view = client.get("/api/robot").json()
    assert not view["open"] and view["outcome"] is None, view


def lose_and_replug(client: TestClient, line: Any) -> dict[str, Any]:
    """Pull the line, wait until the page says the robot stopped, plug it back; the robot's view."""
    line.unplug()
    wait_for(lambda: client.get("/api/robot").json()["error"] is not None)
    line.replug()
    view: dict[str, Any] = client.get("/api/robot").json()
    return view


def test_reconnect_asks_what_the_lost_lines_holding_joints_do_and_does_it(robot: Any) -> None:
    # Reconnect opened the robot as the server's start does: its ICS 3.5 joints free, so a standing robot
    # went limp the moment its line was back.  Holding them at their last targets is right if their servos
    # kept their power (they held those targets meanwhile), wrong if they restarted elsewhere: the page asks.
    client, line = robot
    post(client, "/api/robot/motion", {"enabled": True})
    assert post(client, "/api/robot/move", {"pose": {"shoulder": 20, "elbow": 45}, "duration": 0.1}).status_code == 200
    held = {1: degrees_to_position(20), 2: degrees_to_position(45)}  # (the joints have no offsets)
    wait_for(lambda: {1: line.servo(1).target, 2: line.servo(2).target} == held)
    view = lose_and_replug(client, line)
    assert view["reconnect_choice"] == {"lines": ["arm"], "joints": ["shoulder", "elbow"]}, view
    unsaid = post(client, "/api/robot/reopen")
    assert unsaid.status_code == 400 and "hold" in unsaid.json()["error"] and "free" in unsaid.json()["error"]
    assert post(client, "/api/robot/reopen", {"lost_joints": "maybe"}).status_code == 400
    since = line.transactions
    assert post(client, "/api/robot/reopen", {"lost_joints": "hold"}).json()["open"]
    view = client.get("/api/robot").json()
    assert [j["target"] for j in view["joints"]] == [20.0, 45.0] and view["reconnect_choice"] is None, view
    time.sleep(0.2)  # some cycles on the wire
    sent = line.log_since(since)
    assert sent and not [t for t in sent if t.command == "free"], sent[:4]
    assert {1: line.servo(1).target, 2: line.servo(2).target} == held
    # The other answer: free.
    lose_and_replug(client, line)
    assert post(client, "/api/robot/reopen", {"lost_joints": "free"}).json()["open"]
    wait_for(lambda: line.servo(1).free and line.servo(2).free)
    assert [j["target"] for j in client.get("/api/robot").json()["joints"]] == [None, None]
    # Nothing held when the line went: nothing to ask.
    view = lose_and_replug(client, line)
    assert view["reconnect_choice"] is None, view
    assert post(client, "/api/robot/reopen").json()["open"]


def test_while_a_lost_line_has_stopped_the_robot_its_joints_show_their_last_targets(robot: Any) -> None:
    # Every joint keeps its last command until Reconnect (a holding one holds): the page showed them all
    # "free" meanwhile, beside the question that says they held their targets.
    client, line = robot
    post(client, "/api/robot/motion", {"enabled": True})
    assert post(client, "/api/robot/move", {"pose": {"shoulder": 20}, "duration": 0.1}).status_code == 200
    wait_for(lambda: line.servo(1).target == degrees_to_position(20))
    lose_and_replug(client, line)
    wait_for(lambda: client.get("/api/robot").json()["reconnect_choice"] is not None)
    view = client.get("/api/robot").json()
    assert not view["open"] and [j["target"] for j in view["joints"]] == [20.0, 0.0], view  # (motion on: held)
    assert post(client, "/api/robot/reopen", {"lost_joints": "free"}).json()["open"]
    assert [j["target"] for j in client.get("/api/robot").json()["joints"]] == [None, None]


def test_after_reconnect_the_state_line_says_what_the_lost_lines_joints_do_not_what_they_did_before(
    robot: Any,
) -> None:
    # The state line went on saying "joints hold where they stand" (from before the line was lost) once
    # Reconnect had opened the robot again with the lost line's joints free.
    client, line = robot
    post(client, "/api/robot/motion", {"enabled": True})
    wait_for(lambda: not line.servo(1).free and not line.servo(2).free)
    lose_and_replug(client, line)
    reopened = post(client, "/api/robot/reopen", {"lost_joints": "free"}).json()
    assert reopened["open"] and "hold where they stand" not in (reopened["outcome"] or ""), reopened["outcome"]
    assert "shoulder, elbow" in reopened["outcome"] and "free" in reopened["outcome"], reopened["outcome"]
    wait_for(lambda: line.servo(1).free and line.servo(2).free)
    post(client, "/api/robot/motion", {"enabled": True})
    lose_and_replug(client, line)
    held = post(client, "/api/robot/reopen", {"lost_joints": "hold"}).json()["outcome"]
    assert "shoulder, elbow" in held and "hold their last targets" in held, held


def test_an_offline_joint_shows_no_temperature_or_current(robot: Any) -> None:
    # Its row said "offline" beside the temperature and current read before its servo went silent, as if read.
    client, line = robot
    wait_for(lambda: client.get("/api/robot").json()["joints"][1]["temperature_c"] is not None)
    line.remove_servo(2)
    wait_for(lambda: client.get("/api/robot").json()["joints"][1]["offline"])
    elbow = client.get("/api/robot").json()["joints"][1]
    assert elbow["temperature_c"] is None and elbow["current"] is None, elbow


def test_a_joint_whose_telemetry_reads_keep_failing_shows_no_temperature_or_current(robot: Any) -> None:
    # Its servo answered every cycle, but not its temperature and current reads: its row went on with those read
    # before, as if read now.
    client, line = robot
    wait_for(lambda: client.get("/api/robot").json()["joints"][1]["temperature_c"] is not None)
    line.servo(2).ignores = frozenset({"read_temperature", "read_current"})

    def failed_reads() -> int:
        return sum(1 for t in line.log_since(0) if t.servo_id == 2 and t.command == "read_temperature" and not t.reply)

    wait_for(lambda: failed_reads() >= 4)  # (two of its reads failed at least, with or without a retry each)
    elbow = client.get("/api/robot").json()["joints"][1]
    assert not elbow["offline"] and elbow["position"] is not None, elbow  # (still answering)
    assert elbow["temperature_c"] is None and elbow["current"] is None, elbow
    line.servo(2).ignores = frozenset()
    wait_for(lambda: client.get("/api/robot").json()["joints"][1]["temperature_c"] is not None)  # (read again)


def test_an_offline_joint_is_said_offline_its_target_kept_for_its_slider(tmp_path: Path) -> None:
    # Its target was sent as if it went out: the page showed it, where `ics35 play`'s live table shows "-" (the
    # robot sends an offline servo nothing).  The robot says which joints nothing reaches; the page follows it.
    with arm_page(tmp_path, "[safety]\ncontinue_on_offline = true\n") as (client, line):
        post(client, "/api/robot/motion", {"enabled": True})
        assert post(client, "/api/robot/move", {"pose": {"elbow": 40}, "duration": 0.1}).status_code == 200
        wait_for(lambda: line.servo(2).target == degrees_to_position(40))
        shoulder, elbow = client.get("/api/robot").json()["joints"]
        assert not shoulder["offline"] and not elbow["offline"], (shoulder, elbow)
        line.remove_servo(2)
        wait_for(lambda: client.get("/api/robot").json()["joints"][1]["offline"])
        shoulder, elbow = client.get("/api/robot").json()["joints"]
        assert elbow["offline"] and elbow["target"] == 40.0, elbow
        assert not shoulder["offline"], shoulder
        post(client, "/api/robot/free")


def test_a_joint_held_since_its_servo_answered_again_is_shown_held_not_at_its_old_target(tmp_path: Path) -> None:
    # Its servo went offline and answered again (restarted, free, in a brown-out): the robot sends it nothing
    # until it is told what to do, but the page showed its old target, "ok", as if it still held there.
    with arm_page(tmp_path, '[safety]\naction = "hold"\n') as (client, line):  # (the default frees the others)
        post(client, "/api/robot/motion", {"enabled": True})
        assert post(client, "/api/robot/move", {"pose": {"elbow": 40}, "duration": 0.1}).status_code == 200
        wait_for(lambda: line.servo(2).target == degrees_to_position(40))
        servo = line.remove_servo(2)
        wait_for(lambda: client.get("/api/robot").json()["joints"][1]["offline"])
        servo.power_cycle()
        line.add_device(servo)
        wait_for(lambda: not client.get("/api/robot").json()["joints"][1]["offline"])
        shoulder, elbow = client.get("/api/robot").json()["joints"]
        assert elbow["held"] == "rejoined" and elbow["target"] == 40.0 and servo.free, elbow
        assert shoulder["held"] is None, shoulder
        post(client, "/api/robot/free")


def test_a_joint_held_with_no_target_is_shown_held_while_a_lost_line_stops_the_robot(tmp_path: Path) -> None:
    # The knee, silent at the open, came back held, sent nothing (its servo may bear the robot).  Another line lost,
    # the page showed it "free" until Reconnect, which then asked whether to free it.
    with two_line_page(tmp_path, lower="ids=1") as (client, upper, lower):

        def knee() -> Any:
            return client.get("/api/robot").json()["joints"][3]

        wait_for(lambda: knee()["offline"])
        servo = VirtualServo(2)
        servo.command_position(7000)
        lower.add_device(servo)
        wait_for(lambda: knee()["held"] == "rejoined")
        upper.unplug()
        wait_for(lambda: client.get("/api/robot").json()["error"] is not None)
        assert knee()["held"] == "rejoined" and knee()["target"] is None, knee()


def test_enable_motion_beside_a_held_joint_names_the_pages_way_out_not_the_librarys(tmp_path: Path) -> None:
    # The state line said "set its target once you know where it is", and the slider's move was refused: "Free it".
    with arm_page(tmp_path, '[safety]\naction = "hold"\n') as (client, line):
        post(client, "/api/robot/motion", {"enabled": True})
        servo = line.remove_servo(2)
        wait_for(lambda: client.get("/api/robot").json()["joints"][1]["offline"])
        line.add_device(servo)
        wait_for(lambda: client.get("/api/robot").json()["joints"][1]["held"] == "rejoined")
        post(client, "/api/robot/motion", {"enabled": False})
        said = post(client, "/api/robot/motion", {"enabled": True}).json()["outcome"]
        assert "elbow left as it is: held, sent nothing" in said and "set its target" not in said, said
        assert "the Free button in its row" in said, said


def test_reconnect_keeps_the_other_lines_joints_holding_without_asking(tmp_path: Path) -> None:
    # ID 2 of each line speaks ICS 3.6: read at the start (and again after its line was lost), not asked about.
    joints = (
        '[joints.neck]\nline = "upper"\nid = 1\n[joints.hip]\nline = "lower"\nid = 1\n'
        '[joints.nod]\nline = "upper"\nid = 2\n[joints.tail]\nline = "lower"\nid = 2\n'
    )
    with two_line_page(tmp_path, joints, "ids=1-2&ics36=2", "ids=1-2&ics36=2") as (client, upper, lower):
        post(client, "/api/robot/motion", {"enabled": True})
        pose = {"neck": 10, "hip": -10, "nod": 5, "tail": -5}
        post(client, "/api/robot/move", {"pose": pose, "duration": 0.1})
        held = {"neck": degrees_to_position(10), "nod": degrees_to_position(5), "tail": degrees_to_position(-5)}
        servos = {"neck": upper.servo(1), "nod": upper.servo(2), "tail": lower.servo(2), "hip": lower.servo(1)}
        wait_for(lambda: {name: servos[name].target for name in held} == held and not servos["hip"].free)
        view = lose_and_replug(client, lower)
        assert view["reconnect_choice"] == {"lines": ["lower"], "joints": ["hip"]}, view  # tail: ICS 3.6, read
        since = upper.transactions
        assert post(client, "/api/robot/reopen", {"lost_joints": "free"}).json()["open"]
        wait_for(lambda: lower.servo(1).free)
        time.sleep(0.1)
        assert not [t for t in upper.log_since(since) if t.command == "free"]
        now = {"neck": upper.servo(1).target, "nod": upper.servo(2).target, "tail": lower.servo(2).target}
        assert now == held and not lower.servo(2).free  # the line that stayed holds; tail read, torque as it was
        targets = {j["name"]: j["target"] for j in client.get("/api/robot").json()["joints"]}
        assert targets == {"neck": 10.0, "hip": None, "nod": 5.0, "tail": None}, targets


@pytest.mark.parametrize("answer", ["hold", "free"])
def test_reconnect_asks_about_a_joint_held_since_its_servo_answered_again(tmp_path: Path, answer: str) -> None:
    # A joint whose servo went offline and came back is sent nothing until the program decides: its servo may
    # have restarted (free, elsewhere) or kept its power (holding what it bears).  Another line lost, Reconnect
    # held it at its old target without asking (a restarted servo thrown there); freeing it unasked would drop
    # a holding one.  It is asked about with the lost line's joints, and the answer goes for it too.
    joints = (
        '[joints.neck]\nline = "upper"\nid = 1\n[joints.hip]\nline = "lower"\nid = 1\n'
        '[joints.arm]\nline = "upper"\nid = 2\n[joints.knee]\nline = "lower"\nid = 2\n'
        '[safety]\naction = "hold"\n'
    )
    with two_line_page(tmp_path, joints) as (client, upper, lower):

        def joint(name: str) -> Any:
            return next(j for j in client.get("/api/robot").json()["joints"] if j["name"] == name)

        post(client, "/api/robot/motion", {"enabled": True})
        post(client, "/api/robot/move", {"pose": {"arm": 40, "knee": 30}, "duration": 0.1})
        wait_for(lambda: upper.servo(2).target == degrees_to_position(40))
        wait_for(lambda: lower.servo(2).target == degrees_to_position(30))
        for line, name in ((upper, "arm"), (lower, "knee")):  # offline, and back restarted (free)
            servo = line.remove_servo(2)
            wait_for(lambda: joint(name)["offline"])  # noqa: B023  (waited for here, in its own pass)
            servo.power_cycle()
            line.add_device(servo)
        wait_for(lambda: joint("arm")["held"] == "rejoined" and joint("knee")["held"] == "rejoined")
        view = lose_and_replug(client, lower)
        choice = view["reconnect_choice"]
        assert choice["lines"] == ["lower"] and sorted(choice["joints"]) == ["arm", "hip", "knee"], view
        assert upper.servo(2).free  # (nothing sent to it meanwhile)
        assert post(client, "/api/robot/reopen", {"lost_joints": answer}).json()["open"]
        time.sleep(0.2)  # some cycles on the wire
        if answer == "hold":  # the person says they kept their power: held at their targets
            assert upper.servo(2).target == degrees_to_position(40) and not upper.servo(2).free
            assert lower.servo(2).target == degrees_to_position(30) and not lower.servo(2).free
        else:
            assert upper.servo(2).free and lower.servo(2).free
            assert joint("arm")["target"] is None and joint("knee")["target"] is None


def test_a_start_pose_given_to_the_server_holds_those_joints_from_the_first_command(tmp_path: Path) -> None:
    # ics35 web --robot FILE --start-pose shoulder=20: a standing ICS 3.5 robot need not go limp at the start.
    name = f"web-robot-{next(_names)}"
    path = arm_file(tmp_path, name)
    robot = RobotSession(str(path), start_pose={"shoulder": 20})
    app = create_app(LineSession(LineConfig(port=f"sim://{name}-config")), TOKEN, robot=robot)
    with TestClient(app, base_url=BASE) as client:
        client.cookies.set(COOKIE, TOKEN)
        line = sim.named(name)
        wait_for(lambda: line.servo(2).free and line.servo(1).target is not None)
        commands = [(t.servo_id, t.command) for t in line.log_since(0)]
        assert (1, "free") not in commands and (2, "free") in commands, commands[:6]
        assert [j["target"] for j in client.get("/api/robot").json()["joints"]] == [20.0, None]
    line.close()


def test_the_robot_page_gets_the_joints_over_the_websocket(robot: Any) -> None:
    client, _ = robot
    with client.websocket_connect("ws://127.0.0.1:8766/ws", headers={"origin": BASE}) as ws:
        update = ws.receive_json()
    assert [j["name"] for j in update["robot"]["joints"]] == ["shoulder", "elbow"]
    assert all(j["tripped"] is None for j in update["robot"]["joints"])


def test_the_pages_work_on_a_robot_line_without_fighting_the_robot_for_its_servos(robot: Any) -> None:
    client, line = robot
    status = client.get("/api/status").json()
    assert status["robot"]["lines"][0]["name"] == "arm" and status["robot_line"] is None
    assert post(client, "/api/connect", {"robot_line": "hand"}).status_code == 400  # no such line
    used = post(client, "/api/connect", {"robot_line": "arm"}).json()
    assert used["robot_line"] == "arm" and used["port"].startswith("sim://web-robot-") and used["connected"]
    assert [s["id"] for s in post(client, "/api/scan").json()["servos"]] == [1, 2]
    refused_rates = post(client, "/api/scan", {"bauds": [115200, 1250000]})
    assert refused_rates.status_code == 409 and "its own rate" in refused_rates.json()["error"]
    plan = post(client, "/api/servo/2/plan", {"changes": {"speed": 55}}).json()
    assert post(client, "/api/servo/2/write", {"changes": {"speed": 55}, "before": plan["before"]}).json()["verified"]
    assert line.servo(2).eeprom.speed == 55
    renumber = post(client, "/api/servo/2/plan", {"changes": {"servo_id": 5}, "allow_id_change": True}).json()
    assert "robot's line 'arm'" in renumber["refusal"]
    written = post(client, "/api/servo/2/write", {"changes": {"servo_id": 5}, "allow_id_change": True})
    assert written.status_code == 409 and line.servo(2).eeprom.servo_id == 2
    post(client, "/api/robot/motion", {"enabled": True})  # the robot holds its joints
    wait_for(lambda: line.servo(1).target is not None)
    held = line.servo(1).target
    for path, data in (("free", {}), ("motion", {"enabled": True}), ("move", {"position": 8000})):
        answer = post(client, f"/api/servo/1/{path}", data)
        assert answer.status_code == 409 and "joint shoulder" in answer.json()["error"], path
    assert post(client, "/api/id/survey").status_code == 409
    assert post(client, "/api/live/start", {"ids": [1]}).status_code == 409
    assert line.servo(1).target == held
    cycle = client.get("/api/robot").json()["cycle"]
    back = post(client, "/api/connect", {"port": "sim://", "baud": 115200}).json()
    assert back["robot_line"] is None and back["connected"]
    wait_for(lambda: client.get("/api/robot").json()["cycle"] > cycle + 5)  # the robot streams on, its line open
    assert post(client, "/api/robot/move", {"pose": {"shoulder": 10}, "duration": 0.1}).status_code == 200


def test_a_robot_lines_port_named_with_its_scheme_in_capitals_is_that_robot_line(robot: Any) -> None:
    # SIM://x is sim://x: Connect to the robot's line port so written works on the robot's line, as its own name
    # does, instead of opening the port beside the robot ("already open: a simulated line takes one bus at a time").
    client, _ = robot
    port = client.get("/api/status").json()["robot"]["lines"][0]["port"]
    used = post(client, "/api/connect", {"port": port.replace("sim://", "SIM://")})
    assert used.status_code == 200, used.json()
    assert used.json()["robot_line"] == "arm" and used.json()["connected"]


def test_on_a_robot_line_a_silent_servo_is_not_looked_for_at_other_rates_and_the_message_says_so(robot: Any) -> None:
    client, line = robot
    line.add_device(sim.VirtualServo(5, baud_rate=1250000))
    post(client, "/api/connect", {"robot_line": "arm"})
    cycle = client.get("/api/robot").json()["cycle"]
    answer = client.get("/api/servo/5/eeprom").json()
    assert "answers_at" not in answer and "1,250,000" not in answer["error"], answer
    assert "other rates" in answer["error"] and "robot's line 'arm'" in answer["error"], answer
    assert client.get("/api/status").json()["baud"] == 115200
    wait_for(lambda: client.get("/api/robot").json()["cycle"] > cycle + 5)  # the robot streams on


def test_without_a_port_of_their_own_the_pages_start_on_the_robots_first_line(tmp_path: Path) -> None:
    name = f"web-robot-{next(_names)}"
    path = tmp_path / "one.toml"
    path.write_text(
        f'[lines.arm]\nport = "sim://{name}?ids=1"\nrate_hz = 200\n[joints.shoulder]\nline = "arm"\nid = 1\n'
    )
    session = LineSession(LineConfig(port=f"sim://{name}-unused"))
    app = create_app(session, TOKEN, robot=RobotSession(str(path)), line_from_robot=True)
    with TestClient(app, base_url=BASE) as client:
        client.cookies.set(COOKIE, TOKEN)
        status = client.get("/api/status").json()
        assert status["robot_line"] == "arm" and status["port"] == f"sim://{name}?ids=1" and status["connected"]
        assert [s["id"] for s in post(client, "/api/scan").json()["servos"]] == [1]
    sim.named(name).close()


def test_a_robot_whose_line_is_missing_is_told_in_words_and_the_pages_say_where_they_start(tmp_path: Path) -> None:
    path = tmp_path / "one.toml"
    path.write_text('[lines.arm]\nport = "/dev/ttyUSB-ics35-none"\n[joints.shoulder]\nline = "arm"\nid = 1\n')
    name = f"web-robot-{next(_names)}"
    warned: list[str] = []
    session = LineSession(LineConfig(port=f"sim://{name}?ids=2"))
    app = create_app(session, TOKEN, robot=RobotSession(str(path)), line_from_robot=True, warn=warned.append)
    with TestClient(app, base_url=BASE) as client:
        client.cookies.set(COOKIE, TOKEN)
        status = client.get("/api/status").json()
        assert status["connected"] and status["port"] == f"sim://{name}?ids=2" and status["robot_line"] is None
    assert len(warned) == 2, warned
    opened = f"the robot's lines could not be opened: {path}: line arm: no serial port at '/dev/ttyUSB-ics35-none'"
    assert warned[0].startswith(opened), warned
    assert warned[0].endswith(  # (the library's "open it again" is the Robot page's Reconnect here)
        "; its lines reconnect by themselves to a port lost once the robot is open, not to one missing as it opens:"
        " plug the adapter in, then press Reconnect on the Robot page"
    ), warned
    assert "[Errno" not in warned[0]
    # (not "start on sim:// instead", after the CLI's "the pages start on the robot's first line": until it opens)
    assert f"until the robot is open the pages work on sim://{name}?ids=2 (the built-in simulator)" in warned[1]
    sim.named(name).close()


@pytest.mark.pty
def test_a_robot_line_missing_at_the_start_comes_with_reconnect_and_the_pages_follow_it(
    tmp_path: Path, pty_sim: Any
) -> None:
    # The terminal said "press Reconnect on the Robot page" for the robot and "restart the command" for the pages
    # that were to start on its first line: Reconnect, once the adapter is there, brings both.
    link = tmp_path / "ttyArm"
    path = tmp_path / "one.toml"
    path.write_text(f'[lines.arm]\nport = "{link}"\n[joints.shoulder]\nline = "arm"\nid = 1\n')
    name = f"web-robot-{next(_names)}"
    warned: list[str] = []
    session = LineSession(LineConfig(port=f"sim://{name}?ids=2"))
    app = create_app(session, TOKEN, robot=RobotSession(str(path)), line_from_robot=True, warn=warned.append)
    with TestClient(app, base_url=BASE) as client:
        client.cookies.set(COOKIE, TOKEN)
        assert client.get("/api/status").json()["robot_line"] is None
        assert len(warned) == 2 and not any("restart" in said for said in warned), warned
        assert "press Reconnect on the Robot page" in warned[0], warned
        said = f"until the robot is open the pages work on sim://{name}?ids=2 (the built-in simulator)"
        assert said in warned[1] and "Reconnect" in warned[1], warned
        link.symlink_to(pty_sim("--ids", "1").path)  # the adapter plugged in
        # (the robot's first open, on a serial line: the page is asked before shoulder is freed to read it)
        asked = post(client, "/api/robot/reopen", {})
        assert asked.json()["start_free_choice"] == {"joints": ["shoulder"]}, asked.json()
        assert client.get("/api/status").json()["robot_line"] is None  # (not open: the pages stay)
        reopened = post(client, "/api/robot/reopen", {"start_free": ["shoulder"]})
        assert reopened.status_code == 200 and reopened.json()["open"], reopened.json()
        status = client.get("/api/status").json()
        assert status["robot_line"] == "arm" and status["port"] == str(link) and status["connected"], status
        assert [s["id"] for s in post(client, "/api/scan").json()["servos"]] == [1]
    sim.named(name).close()


@pytest.mark.pty
def test_a_port_chosen_while_the_robot_was_missing_stays_the_pages_at_reconnect(tmp_path: Path, pty_sim: Any) -> None:
    # The pages follow the robot's first line only from where they stood in for it: a port the person chose
    # meanwhile is theirs.
    link = tmp_path / "ttyArm"
    path = tmp_path / "one.toml"
    path.write_text(f'[lines.arm]\nport = "{link}"\n[joints.shoulder]\nline = "arm"\nid = 1\n')
    name = f"web-robot-{next(_names)}"
    session = LineSession(LineConfig(port=f"sim://{name}?ids=2"))
    robot = RobotSession(str(path), ask_before_freeing=False)  # (--yes: Reconnect opens it at once)
    app = create_app(session, TOKEN, robot=robot, line_from_robot=True)
    with TestClient(app, base_url=BASE) as client:
        client.cookies.set(COOKIE, TOKEN)
        chosen = f"sim://{name}-chosen?ids=3"
        assert post(client, "/api/connect", {"port": chosen}).json()["connected"]
        link.symlink_to(pty_sim("--ids", "1").path)
        assert post(client, "/api/robot/reopen", {}).json()["open"]
        status = client.get("/api/status").json()
        assert status["robot_line"] is None and status["port"] == chosen, status
    sim.named(name).close()
    sim.named(f"{name}-chosen").close()


@contextlib.contextmanager
def standing_arm(
    tmp_path: Path, ask: bool = True, ics36: tuple[int, ...] = (2,), absent: tuple[int, ...] = ()
) -> Iterator[tuple[PtyLine, TestClient, list[str]]]:
    """An arm on a serial line (a pty): shoulder on servo 1, elbow on servo 2 (ICS 3.6 unless ``ics36`` says not),
    each holding 7000 as the server starts but those ``absent`` (unplugged); ``ask``: the server asks before freeing
    (``ics35 web --robot`` without --yes); the pages on the robot's line (no --port given).  The line, the
    signed-in client and what the server warned of."""
    line = PtyLine((1, 2), ics36=ics36)
    for servo in line.sim.servos:
        servo.command_position(7000)
    for servo_id in absent:
        line.sim.remove_servo(servo_id)
    path = tmp_path / "arm.toml"
    path.write_text(
        f'[lines.arm]\nport = "{line.path}"\n[joints.shoulder]\nline = "arm"\nid = 1\n'
        '[joints.elbow]\nline = "arm"\nid = 2\n'
    )
    warned: list[str] = []
    session = LineSession(LineConfig(port=f"sim://web-robot-{next(_names)}?ids=3"))
    robot = RobotSession(str(path), ask_before_freeing=ask)
    app = create_app(session, TOKEN, robot=robot, warn=warned.append, line_from_robot=True)
    try:
        with TestClient(app, base_url=BASE) as client:
            client.cookies.set(COOKIE, TOKEN)
            yield line, client, warned
    finally:
        line.close()


@pytest.mark.pty
def test_a_robot_on_a_serial_line_frees_no_ics35_joint_at_the_servers_start_until_the_robot_page_says_so(
    tmp_path: Path,
) -> None:
    # `ics35 web --robot` freed the ICS 3.5 joints it read at its start without a word (`play` asks): a humanoid
    # standing on them fell as the server started, before any page was open.
    with standing_arm(tmp_path) as (line, client, warned):
        view = client.get("/api/robot").json()
        assert not view["open"] and view["start_free_choice"] == {"joints": ["shoulder"]}, view
        asks = "the robot is not open, nothing freed: it waits for the answer to its question (below)"
        assert view["error"] == asks, view
        # What else is asked of the robot meanwhile is refused in the page's words, not the terminal's.
        for path, data in (("/api/robot/free", {}), ("/api/robot/stop", {}), ("/api/robot/motion", {"enabled": True})):
            refused = post(client, path, data)
            said = refused.json()["error"]
            assert refused.status_code == 409 and "its question" in said and "--yes" not in said, (path, said)
            assert "Reconnect" not in said, (path, said)
        # (nothing was sent to them: none is shown free, as if it were not bearing the robot)
        assert [(j["target"], j["uncommanded"]) for j in view["joints"]] == [(None, True)] * 2, view
        said = "the robot was not opened, nothing freed: joint shoulder speaks ICS 3.5, whose position is read only by"
        assert len(warned) == 2 and said in warned[0] and "--start-pose" in warned[0], warned
        assert "(the built-in simulator): the Robot page's question, answered, brings them" in warned[1], warned
        assert client.get("/api/status").json()["robot_line"] is None
        assert line.sim.servo(1).target == 7000  # nothing freed it
        # Reconnect without the answer: asked again, nothing freed.
        again = post(client, "/api/robot/reopen", {})
        assert again.status_code == 200 and not again.json()["open"], again.json()
        assert again.json()["start_free_choice"] == {"joints": ["shoulder"]}
        assert line.sim.servo(1).target == 7000
        # The page's answer: the joints it named are freed to read them, and the robot opens.
        opened = post(client, "/api/robot/reopen", {"start_free": ["shoulder"]})
        assert opened.status_code == 200 and opened.json()["open"], opened.json()
        assert opened.json()["start_free_choice"] is None and opened.json()["error"] is None
        assert line.sim.servo(1).free
        assert client.get("/api/status").json()["robot_line"] == "arm"  # (the pages follow it there)
        # (its first open: not "reconnected"; what it freed, said)
        assert opened.json()["outcome"] == "opened: shoulder freed to read where it stands", opened.json()


@pytest.mark.pty
def test_the_robot_pages_answer_covers_only_the_joints_it_named(tmp_path: Path) -> None:
    # An answer naming another joint (the elbow: ICS 3.6, read without freeing) frees nothing of the shoulder.
    with standing_arm(tmp_path) as (line, client, _):
        refused = post(client, "/api/robot/reopen", {"start_free": ["elbow"]})
        assert not refused.json()["open"] and refused.json()["start_free_choice"] == {"joints": ["shoulder"]}
        assert line.sim.servo(1).target == 7000
        bad = post(client, "/api/robot/reopen", {"start_free": "shoulder"})
        assert bad.status_code == 400 and "start_free" in bad.json()["error"], bad.json()
        assert line.sim.servo(1).target == 7000


@pytest.mark.pty
def test_the_robot_pages_answers_add_up(tmp_path: Path) -> None:
    # (a servo answering only after the first answer: asked about alone, and the robot opens)
    with standing_arm(tmp_path, ics36=(), absent=(2,)) as (line, client, _):
        assert client.get("/api/robot").json()["start_free_choice"] == {"joints": ["shoulder"]}
        elbow = VirtualServo(2)  # (the elbow's servo plugged in, holding)
        elbow.command_position(7000)
        line.sim.add_device(elbow)
        again = post(client, "/api/robot/reopen", {"start_free": ["shoulder"]}).json()
        assert not again["open"] and again["start_free_choice"] == {"joints": ["elbow"]}, again
        assert line.sim.servo(1).target == 7000 and line.sim.servo(2).target == 7000  # (nothing freed yet)
        opened = post(client, "/api/robot/reopen", {"start_free": ["elbow"]}).json()
        assert opened["open"] and line.sim.servo(1).free and line.sim.servo(2).free, opened


@pytest.mark.pty
def test_a_joint_silent_while_the_question_waits_is_named_beside_it(tmp_path: Path) -> None:
    # The question named the shoulder alone, and nothing said why the elbow was left out (its servo did not answer)
    # until the robot had opened.
    with standing_arm(tmp_path, ics36=(), absent=(2,)) as (_, client, warned):
        view = client.get("/api/robot").json()
        assert view["start_free_choice"] == {"joints": ["shoulder"]}, view
        assert any("joints.elbow" in said and "did not answer" in said for said in view["warnings"]), view
        assert any("joints.elbow" in said and "did not answer" in said for said in warned), warned
        # (kept under the title once it answers: said of the open, it stays true)
        assert any("did not answer as the robot opened" in said for said in view["warnings"]), view


@pytest.mark.pty
def test_a_line_lost_while_the_question_waits_is_said_not_hidden_behind_it(tmp_path: Path) -> None:
    with standing_arm(tmp_path) as (line, client, _):
        line.sim.unplug()
        wait_for(lambda: not os.path.lexists(line.path))  # (the pty's server follows the unplug in a thread of its own)
        answered = post(client, "/api/robot/reopen", {"start_free": ["shoulder"]}).json()
        assert not answered["open"] and answered["start_free_choice"] is None, answered
        assert answered["error"].startswith("the robot's lines could not be opened"), answered
        assert line.sim.servo(1).target == 7000
        # Back: a plain Reconnect asks again (that answer was for that open: the robot may stand otherwise now).
        line.sim.replug()
        wait_for(lambda: os.path.exists(line.path))  # (and makes its link again)
        again = post(client, "/api/robot/reopen", {}).json()
        assert not again["open"] and again["start_free_choice"] == {"joints": ["shoulder"]}, again
        assert line.sim.servo(1).target == 7000


def lose_and_replug_pty(client: TestClient, line: PtyLine) -> None:
    """Pull a pty line out until the Robot page says the robot stopped, then plug it back in."""
    line.sim.unplug()
    wait_for(lambda: client.get("/api/robot").json()["error"] is not None)
    line.sim.replug()
    wait_for(lambda: os.path.exists(line.path))  # (the pty's server makes its link again in a thread of its own)


@pytest.mark.pty
def test_reconnect_asks_before_freeing_a_joint_held_since_it_answered_again_with_no_target(tmp_path: Path) -> None:
    # The elbow's servo, silent at the open (a loose signal wire), came back held, sent nothing: it bears what it
    # bore.  The line lost and back, Reconnect read it by freeing it, unasked, as if it had been free.
    with standing_arm(tmp_path, ics36=(), absent=(2,)) as (line, client, _):
        assert post(client, "/api/robot/reopen", {"start_free": ["shoulder"]}).json()["open"]
        elbow = VirtualServo(2)
        elbow.command_position(7000)
        line.sim.add_device(elbow)
        wait_for(lambda: client.get("/api/robot").json()["joints"][1]["held"] == "rejoined")
        lose_and_replug_pty(client, line)
        asked = post(client, "/api/robot/reopen", {}).json()
        # (the shoulder, freed at the open and free since, is not asked about again: freeing it changes nothing)
        assert not asked["open"] and asked["start_free_choice"] == {"joints": ["elbow"]}, asked
        assert elbow.target == 7000 and not elbow.free
        opened = post(client, "/api/robot/reopen", {"start_free": ["elbow"]}).json()
        assert opened["open"] and elbow.free, opened


@contextlib.contextmanager
def arm_lost_holding_and_held(tmp_path: Path) -> Iterator[tuple[PtyLine, TestClient, VirtualServo]]:
    """A :func:`standing_arm` of two ICS 3.5 joints, its line lost and back: the shoulder held a target (20 degrees)
    when it went, the elbow's servo (holding 7000) was held, sent nothing, since it answered after the open.  The
    line, the client and the elbow's servo."""
    with standing_arm(tmp_path, ics36=(), absent=(2,)) as (line, client, _):
        assert post(client, "/api/robot/reopen", {"start_free": ["shoulder"]}).json()["open"]
        post(client, "/api/robot/motion", {"enabled": True})
        assert post(client, "/api/robot/move", {"pose": {"shoulder": 20}, "duration": 0.1}).status_code == 200
        wait_for(lambda: line.sim.servo(1).target == degrees_to_position(20))
        elbow = VirtualServo(2)
        elbow.command_position(7000)
        line.sim.add_device(elbow)
        wait_for(lambda: client.get("/api/robot").json()["joints"][1]["held"] == "rejoined")
        lose_and_replug_pty(client, line)
        yield line, client, elbow


@pytest.mark.pty
def test_reconnects_answer_for_the_lost_lines_joints_stands_while_its_open_asks_before_freeing(tmp_path: Path) -> None:
    # The shoulder held a target when the line went (Reconnect asks whether it still holds it); the elbow came back
    # held with none (the open asks before freeing it).  Answered in turn, each answer is kept, not asked again.
    with arm_lost_holding_and_held(tmp_path) as (line, client, elbow):
        told: list[str] = []
        client.app.state.robot.tell = told.append  # (the server's terminal)
        assert client.get("/api/robot").json()["reconnect_choice"] == {"lines": ["arm"], "joints": ["shoulder"]}
        asked = post(client, "/api/robot/reopen", {"lost_joints": "hold"}).json()
        assert not asked["open"] and asked["start_free_choice"] == {"joints": ["elbow"]}, asked
        # (the terminal, told the robot stopped, hears that Reconnect left it closed for the page's question)
        said = "Reconnect did not open the robot, nothing freed: joint elbow speaks ICS 3.5"
        assert len(told) == 1 and told[0].startswith(said) and "the Robot page asks" in told[0], told
        assert asked["reconnect_choice"] is None, asked  # (answered: the page asks only what is left)
        assert elbow.target == 7000 and not elbow.free
        opened = post(client, "/api/robot/reopen", {"start_free": ["elbow"]}).json()
        assert opened["open"] and elbow.free, opened
        assert opened["outcome"] == "reconnected; shoulder holds its last target; elbow freed to read where it stands"
        time.sleep(0.1)
        assert line.sim.servo(1).target == degrees_to_position(20) and not line.sim.servo(1).free


@pytest.mark.pty
def test_reconnects_answer_for_the_lost_lines_joints_is_for_the_open_it_was_given_to(tmp_path: Path) -> None:
    # Kept while the open's question kept the robot closed; but an open that failed for a missing line kept it too,
    # and the next Reconnect held the joints at their old targets unasked (their servos may have restarted since).
    with arm_lost_holding_and_held(tmp_path) as (line, client, _):
        asked = post(client, "/api/robot/reopen", {"lost_joints": "hold"}).json()
        assert asked["start_free_choice"] == {"joints": ["elbow"]}, asked
        # (while the question waits, the elbow is shown as it was left: held, sent nothing)
        assert asked["joints"][1]["held"] == "rejoined" and asked["joints"][1]["target"] is None, asked
        line.sim.unplug()
        wait_for(lambda: not os.path.lexists(line.path))
        failed = post(client, "/api/robot/reopen", {"start_free": ["elbow"]}).json()
        assert not failed["open"] and failed["error"].startswith("the robot's lines could not be opened"), failed
        line.sim.replug()
        wait_for(lambda: os.path.exists(line.path))
        again = post(client, "/api/robot/reopen", {"start_free": ["elbow"]})
        assert again.status_code == 400 and "say whether they hold" in again.json()["error"], again.json()
        assert client.get("/api/robot").json()["reconnect_choice"] == {"lines": ["arm"], "joints": ["shoulder"]}


@pytest.mark.pty
def test_a_joint_silent_at_a_reconnect_comes_back_held_not_freed(tmp_path: Path) -> None:
    # The robot's first open asked before freeing, so a joint silent then came back held; one silent at
    # Reconnect's open was freed the moment its servo answered (the free was its probe).
    with standing_arm(tmp_path, ics36=()) as (line, client, _):
        assert post(client, "/api/robot/reopen", {"start_free": ["shoulder", "elbow"]}).json()["open"]
        elbow = line.sim.servo(2)
        assert elbow.free  # (freed to read it, as the page's answer said)
        lose_and_replug_pty(client, line)
        line.sim.remove_servo(2)  # (its signal wire loose now; its power on: it holds 7000 meanwhile)
        elbow.command_position(7000)
        opened = post(client, "/api/robot/reopen", {}).json()
        assert opened["open"] and opened["start_free_choice"] is None, opened
        wait_for(lambda: client.get("/api/robot").json()["joints"][1]["offline"])
        line.sim.add_device(elbow)
        wait_for(lambda: client.get("/api/robot").json()["joints"][1]["held"] == "rejoined")
        assert elbow.target == 7000 and not elbow.free


@pytest.mark.pty
def test_told_not_to_ask_the_server_opens_the_robot_at_its_start_freeing_its_ics35_joints(tmp_path: Path) -> None:
    # (`ics35 web --robot FILE --yes`)
    with standing_arm(tmp_path, ask=False) as (line, client, warned):
        view = client.get("/api/robot").json()
        assert view["open"] and view["start_free_choice"] is None, view
        assert line.sim.servo(1).free and not any("shoulder" in said for said in warned), warned


def test_the_robots_open_warnings_reach_the_servers_warn_not_a_raw_python_warning(tmp_path: Path) -> None:
    # A joint whose file allows more than its servo's EEPROM pulse limits: said as the command's other
    # start-up problems are, in its own words, not as a Python warning pointing into a library.
    name = f"web-robot-{next(_names)}"
    line = sim.VirtualLine([1, 2], name=name)
    elbow = line.servo(2)
    elbow.eeprom = elbow.eeprom.replace(pulse_limit_high=9000)  # the file's 90 degrees are about 10,200
    path = arm_file(tmp_path, name)
    warned: list[str] = []
    app = create_app(
        LineSession(LineConfig(port=f"sim://{name}-config")), TOKEN, robot=RobotSession(str(path)), warn=warned.append
    )
    with warnings.catch_warnings(record=True) as raw:
        warnings.simplefilter("always")
        with TestClient(app, base_url=BASE) as client:
            client.cookies.set(COOKIE, TOKEN)
            view = client.get("/api/robot").json()
    line.close()
    assert view["open"] and view["warnings"] == warned, view  # the Robot page shows them too
    assert len(warned) == 1, warned
    assert f"{path}: joints.elbow: the file allows 0..90 degrees, but servo ID 2 on line arm" in warned[0], warned
    assert not [w for w in raw if issubclass(w.category, RobotWarning)], [str(w.message) for w in raw]


def test_the_robots_lines_open_with_the_line_options_given(tmp_path: Path) -> None:
    """``ics35 web --timeout 0.3 --robot FILE``: the robot's lines wait for replies as long as asked, as
    ``ics35 play`` does (the CLI hands its --timeout and --transport to the session)."""
    name = f"web-robot-{next(_names)}"
    path = tmp_path / "one.toml"
    path.write_text(
        f'[lines.arm]\nport = "sim://{name}?ids=1"\nrate_hz = 200\n[joints.shoulder]\nline = "arm"\nid = 1\n'
    )
    robot = RobotSession(str(path), {"adapter_latency": 0.3})
    app = create_app(LineSession(LineConfig(port=f"sim://{name}-unused")), TOKEN, robot=robot)
    with TestClient(app, base_url=BASE) as client:
        client.cookies.set(COOKIE, TOKEN)
        bus, _ = robot.line("arm")
        assert bus.timing.adapter_latency == 0.3
        assert client.get("/api/robot").json()["cycle"] >= 0
    sim.named(name).close()


def test_a_pushed_robot_state_is_what_the_robot_is_when_it_is_sent_not_before_a_telemetry_round(tmp_path: Path) -> None:
    # The pages' once-a-second telemetry round waits for the line (here each read waits out its
    # allowance); an answer the page gets meanwhile (motion on) must not be followed by a push saying
    # what was before it: the page would flip the box back until the next push.
    arm = f"web-robot-{next(_names)}"
    robot = RobotSession(str(arm_file(tmp_path, arm)))
    name = f"web-robot-slow-{next(_names)}"
    session = LineSession(LineConfig(port=f"sim://{name}?ids=1-4"))
    pushed: list[dict[str, Any]] = []

    class Page:  # what the push needs of a page's WebSocket
        app = SimpleNamespace(state=SimpleNamespace(session=session, robot=robot))
        query_params: Mapping[str, str] = MappingProxyType({})  # (a page that gives no name)

        async def accept(self) -> None:
            pass

        async def receive_json(self) -> Any:
            await asyncio.Event().wait()  # the page says nothing

        async def send_json(self, update: dict[str, Any]) -> None:
            pushed.append(update)

    async def main() -> None:
        await robot.open()
        await session.connect()
        try:
            assert len((await session.scan(ids=[1, 2, 3, 4]))["servos"]) == 4
            slow = sim.named(name)
            for servo in slow.servos:
                servo.ignores = frozenset({"read_temperature"})
            start = slow.log[-1].seq + 1
            pushing = asyncio.create_task(updates(Page()))  # type: ignore[arg-type]
            while not slow.log_since(start):  # the first round has begun (it reads at once)
                await asyncio.sleep(0.001)
            await robot.set_motion(True)  # what the page's tick does (/api/robot/motion)
            while not any("servos" in u for u in pushed):
                await asyncio.sleep(0.005)
            pushing.cancel()
        finally:
            await session.close()
            await robot.close()
            sim.named(name).close()
            sim.named(arm).close()

    asyncio.run(main())
    first = next(u for u in pushed if "servos" in u)
    assert first["robot"]["motion_enabled"], "the push said what the robot was before the answer"


@pytest.mark.parametrize("off", ["page gone", "switched off"])
def test_a_move_asked_as_motion_goes_off_does_not_start_once_the_last_motion_stopped(tmp_path: Path, off: str) -> None:
    # A Play (or Move) waits for the motion playing to stop smoothly before it starts; motion went off
    # meanwhile (its page gone, or the switch): it started anyway, and moved a robot with motion off.
    name = f"web-robot-{next(_names)}"
    robot = RobotSession(str(arm_file(tmp_path, name)))

    def reach(label: str, degrees: float) -> dict[str, Any]:
        return {
            "format": "ics35-motion",
            "version": 1,
            "name": label,
            "keyframes": [{"time": 5.0, "pose": {"shoulder": degrees}}],
        }

    async def main() -> None:
        await robot.open()
        try:
            await robot.set_motion(True, "p1")
            await robot.play(reach("first", 50))
            await asyncio.sleep(0.3)
            second = asyncio.create_task(robot.play(reach("second", -20)))
            await asyncio.sleep(0.05)  # (inside the first's smooth stop: 0.3 s)
            if off == "page gone":
                robot.page_gone("p1", "tab closed")
            else:
                await robot.set_motion(False)
            with pytest.raises(UnsafeOperation, match="enable motion"):
                await second
            await robot.settled()
            assert not robot.motion_enabled and robot.playing is None, (robot.playing, robot.outcome)
            held = sim.named(name).servo(1).target
            await asyncio.sleep(0.6)
            assert sim.named(name).servo(1).target == held  # nothing drives the joints
        finally:
            await robot.close()
            sim.named(name).close()

    asyncio.run(main())


def test_free_all_while_a_line_is_lost_frees_the_other_lines_and_names_the_lost_ones(tmp_path: Path) -> None:
    # A lost line closed the robot, and Free all was refused, while the other line's joints went on holding their
    # last targets: a robot half-stopped could not be made limp.
    with two_line_page(tmp_path) as (client, upper, lower):
        post(client, "/api/robot/motion", {"enabled": True})
        post(client, "/api/robot/move", {"pose": {"neck": 10, "arm": 20, "hip": -10, "knee": 30}, "duration": 0.1})
        wait_for(lambda: not any(s.free for s in (*upper.servos, *lower.servos)))
        lower.unplug()
        wait_for(lambda: client.get("/api/robot").json()["error"] is not None)
        early = post(client, "/api/robot/reopen")  # (before the line is back: the robot stays as it is)
        assert early.status_code == 409 and "still lost" in early.json()["error"], early.json()
        freed = post(client, "/api/robot/free")
        assert freed.status_code == 200, freed.json()
        # Confirmed on the wire when it answers: the upper line's servos are free now.
        assert upper.servo(1).free and upper.servo(2).free
        assert not lower.servo(1).free and not lower.servo(2).free  # (not reached: they hold on)
        view = freed.json()
        said = view["outcome"]
        assert "hip, knee" in said and "may still hold" in said and "neck" not in said, said
        # When their free goes out, said: the moment the line is back (it said "Reconnect frees them", and a robot
        # plugged back in went limp before anyone pressed it).
        assert "they go free the moment the line is back: hold the robot as you plug it in" in said, said
        assert [j["target"] for j in view["joints"]] == [None, None, None, None], view
        assert [j["free_when_back"] for j in view["joints"]] == [False, False, True, True], view
        # Reconnect follows the freeing: nothing to ask about, and nothing held again.
        assert view["reconnect_choice"] is None, view
        lower.replug()
        wait_for(lambda: lower.servo(1).free and lower.servo(2).free)  # (as said: before Reconnect)
        wait_for(lambda: not any(j["free_when_back"] for j in client.get("/api/robot").json()["joints"]))
        reopened = post(client, "/api/robot/reopen")
        assert reopened.status_code == 200 and reopened.json()["open"], reopened.json()
        wait_for(lambda: all(s.free for s in (*upper.servos, *lower.servos)))
        time.sleep(0.2)  # some cycles on the wire: nothing takes hold again
        assert all(s.free for s in (*upper.servos, *lower.servos))
        assert [j["target"] for j in client.get("/api/robot").json()["joints"]] == [None] * 4


def test_free_all_frees_a_lost_lines_ics36_joint_at_reconnect(tmp_path: Path) -> None:
    # An ICS 3.6 joint is read at an open, its torque left as it is: freed by Free all while its line was lost, it
    # went on holding after Reconnect.
    joints = '[joints.neck]\nline = "upper"\nid = 1\n[joints.tail]\nline = "lower"\nid = 1\n'
    with two_line_page(tmp_path, joints, "ids=1", "ids=1&ics36=1") as (client, upper, lower):
        post(client, "/api/robot/motion", {"enabled": True})
        post(client, "/api/robot/move", {"pose": {"neck": 10, "tail": 30}, "duration": 0.1})
        wait_for(lambda: lower.servo(1).target == degrees_to_position(30) and not upper.servo(1).free)
        lower.unplug()
        wait_for(lambda: client.get("/api/robot").json()["error"] is not None)
        assert post(client, "/api/robot/free").status_code == 200
        assert upper.servo(1).free and not lower.servo(1).free
        lower.replug()
        assert post(client, "/api/robot/reopen").json()["open"]
        wait_for(lambda: lower.servo(1).free)


def test_a_motion_on_a_robot_whose_only_line_is_lost_says_it_stopped_not_that_it_went_on_with_others(
    robot: Any,
) -> None:
    # "line arm lost its port: the motion gave its joints up ... and went on with the others": there were none.
    client, line = robot
    post(client, "/api/robot/motion", {"enabled": True})
    wait_for(lambda: line.servo(1).target is not None)
    reach = [{"time": 5.0, "pose": {"shoulder": 50, "elbow": 60}}]
    motion = {"format": "ics35-motion", "version": 1, "name": "reach", "keyframes": reach}
    assert post(client, "/api/robot/play", {"motion": motion}).json()["playing"] == "reach"
    line.unplug()
    wait_for(lambda: client.get("/api/robot").json()["outcome"] is not None)
    said = client.get("/api/robot").json()["outcome"]
    assert said.startswith("reach: ") and "lost" in said and "stopped" in said and "other" not in said, said


def test_free_all_on_a_robot_whose_only_line_is_lost_answers_at_once(robot: Any) -> None:
    client, line = robot
    post(client, "/api/robot/motion", {"enabled": True})
    wait_for(lambda: not line.servo(1).free and not line.servo(2).free)
    line.unplug()
    wait_for(lambda: client.get("/api/robot").json()["error"] is not None)
    # (a robot of one line has no other lines: its words spoke of them all the same)
    early = post(client, "/api/robot/reopen").json()["error"]
    assert "still lost" in early and "other lines" not in early, early
    stopped = post(client, "/api/robot/stop").json()["error"]
    assert "lines still there" not in stopped and "Free all" in stopped, stopped
    freed = post(client, "/api/robot/free")
    said = freed.json()["outcome"]
    assert freed.status_code == 200 and said.startswith("shoulder, elbow not reached (line arm lost)"), said
    line.replug()
    assert post(client, "/api/robot/reopen").json()["open"]
    wait_for(lambda: line.servo(1).free and line.servo(2).free)


def test_stop_with_the_robot_stopped_by_a_lost_line_says_how_it_stands_and_what_to_do(robot: Any) -> None:
    # It answered with the robot's view, unchanged: the page said nothing, as if the robot had stopped on the press.
    client, line = robot
    post(client, "/api/robot/motion", {"enabled": True})
    wait_for(lambda: not line.servo(1).free)
    line.unplug()
    wait_for(lambda: client.get("/api/robot").json()["error"] is not None)
    answer = post(client, "/api/robot/stop")
    said = answer.json()["error"]
    assert answer.status_code == 409 and "not open" in said and "Free all" in said and "Reconnect" in said, said
    assert "keep their last" in said, said


def test_a_lost_line_back_before_the_motion_playing_has_slowed_to_rest_is_still_the_one_reconnect_asks_about(
    tmp_path: Path,
) -> None:
    # The page worked the lost line out again from the buses' states once the motion playing on the other line had
    # slowed to rest: a line back by then (an adapter that only wiggled) was no lost line, and Reconnect's question
    # named no line ("line  held joints hip, knee"), or, a cycle earlier, its joints were held again unasked.
    with two_line_page(tmp_path) as (client, upper, lower):
        post(client, "/api/robot/motion", {"enabled": True})
        post(client, "/api/robot/move", {"pose": {"hip": -10, "knee": 30}, "duration": 0.1})
        wait_for(lambda: lower.servo(1).target == degrees_to_position(-10))
        # A long move on the other line: the lost line's stop slows it to rest over the stop's ramp.
        assert post(client, "/api/robot/move", {"pose": {"neck": 60}, "duration": 3}).status_code == 200
        wait_for(lambda: upper.servo(1).target > degrees_to_position(10))  # (under way: a stop has a ramp)
        lower.unplug()
        lower.replug()  # (back at the first reconnect attempt, within the stop's ramp)
        wait_for(lambda: client.get("/api/robot").json()["error"] is not None)
        # Reconnect's question with its offer (it came only once the stop's ramp was over), naming the line
        view = client.get("/api/robot").json()
        assert view["reconnect_choice"] == {"lines": ["lower"], "joints": ["hip", "knee"]}, view
        unsaid = post(client, "/api/robot/reopen")
        assert unsaid.status_code == 400 and "line lower held joints hip, knee" in unsaid.json()["error"]
        assert post(client, "/api/robot/reopen", {"lost_joints": "free"}).json()["open"]
        wait_for(lambda: lower.servo(1).free and lower.servo(2).free)


def test_reconnect_pressed_while_the_other_lines_slow_to_rest_does_not_send_them_back(tmp_path: Path) -> None:
    # The lost line back at once (a reconnect delay: 0.05 s), Reconnect pressed within the stop's ramp: the robot
    # reopened holding the other lines' joints where the ramp was as Reconnect was pressed, and the neck, come to
    # rest further on, was sent back there.
    with two_line_page(tmp_path) as (client, upper, lower):
        post(client, "/api/robot/motion", {"enabled": True})
        post(client, "/api/robot/move", {"pose": {"neck": 60}, "duration": 3.0})
        time.sleep(0.5)
        since = upper.transactions
        lower.unplug()
        wait_for(lambda: client.get("/api/robot").json()["error"] is not None, 5)
        lower.replug()
        answer = post(client, "/api/robot/reopen", {"lost_joints": "free"})
        assert answer.status_code == 200, answer.json()
        time.sleep(0.5)
        sent = [(t.tx[1] << 7) | t.tx[2] for t in upper.log_since(since) if t.servo_id == 1 and t.command == "position"]
        assert len(set(sent)) > 2 and sent == sorted(sent), sent  # (moving up to 60 degrees, then at rest)
