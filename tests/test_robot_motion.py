"""Motion files: the format's checks, and playing keyframes on two simulated lines (read back from the log)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import anyio
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ics35_async import InvalidArgument, Robot, SafetyStop, open_robot
from ics35_async.robot import (
    Keyframe,
    Motion,
    MotionError,
    MotionStopped,
    load_description,
    load_motion,
    parse_motion,
    save_motion,
)
from tests.support.robot_rig import JOINTS, Rig, joint_position, make_rig, sent_position, targets_sent
from tests.support.timing import FAST, GUARD


def motion(*keyframes: dict[str, Any], **top: Any) -> dict[str, Any]:
    return {"format": "ics35-motion", "version": 1, **top, "keyframes": list(keyframes)}


def play_on(rig: Rig, data: Any, **options: Any) -> dict[str, int]:
    """Play ``data`` on a fresh robot; return the log seqs at the start."""
    since: dict[str, int] = {}

    async def main() -> None:
        with anyio.fail_after(GUARD):
            async with open_robot(rig.description, **FAST) as robot:
                await robot.read_pose()
                since.update(upper=rig.upper.transactions, lower=rig.lower.transactions)
                await robot.play(data, **options)

    try:
        anyio.run(main)
    finally:
        rig.close()
    return since


def check_played(rig: Rig, since: dict[str, int], played: Motion) -> None:
    """Within limits; direction changes only at keyframe angles; each joint ends at its last keyframe angle."""
    for name, spec in JOINTS.items():
        sent = targets_sent(rig.sim(spec["line"]), spec["id"], since[spec["line"]])
        low, high = sorted((sent_position(spec, spec["min"]), sent_position(spec, spec["max"])))
        assert all(low <= p <= high for p in sent), name
        angles = [f.pose[name] for f in played.keyframes if name in f.pose]
        if not angles:
            assert sent == [], name  # a joint the motion never names is not touched
            continue
        assert sent[-1] == sent_position(spec, angles[-1]), name
        turns = {sent_position(spec, a) for a in angles}
        path = [p for k, p in enumerate(sent) if k == 0 or p != sent[k - 1]]
        for a, b, c in zip(path, path[1:], path[2:], strict=False):
            if (b - a) * (c - b) < 0:
                assert b in turns, (name, path)


def test_play_goes_through_every_keyframe_and_leaves_unnamed_joints_alone(tmp_path: Path) -> None:
    data = motion(
        {"time": 0.15, "pose": {"neck": 30.0, "hip": -20.0}},
        {"time": 0.3, "pose": {"neck": -30.0}, "profile": "linear"},
        {"time": 0.5, "pose": {"neck": 10.0, "hip": 25.0}},
        name="test",
    )
    path = tmp_path / "m.json"
    path.write_text(json.dumps(data))
    played = load_motion(path)
    assert (played.name, played.duration, played.joints) == ("test", 0.5, ["neck", "hip"])
    rig = make_rig()
    since = play_on(rig, path, speed=2.0)
    check_played(rig, since, played)
    # hip is not in the second keyframe: it holds -20 through that segment, so it turns there only.
    hip = targets_sent(rig.lower, 1, since["lower"])
    assert joint_position(JOINTS["hip"], -20.0) in hip


def test_keyframes_closer_than_a_cycle_are_each_sent_in_order() -> None:
    """Frames further apart than a segment: no keyframe is skipped, each one goes on the wire exactly, in order."""
    data = motion(
        {"time": 0.005, "pose": {"neck": 30.0}},
        {"time": 0.01, "pose": {"neck": -30.0}},
        {"time": 0.015, "pose": {"neck": 10.0}},
        {"time": 0.02, "pose": {"neck": -20.0}},
    )
    rig = make_rig()
    since = play_on(rig, data, speed=10.0)  # segments of 0.5 ms: several in every cycle of the line
    sent = targets_sent(rig.upper, 1, since["upper"])
    keys = [joint_position(JOINTS["neck"], a) for a in (30.0, -30.0, 10.0, -20.0)]
    rest = iter(sent)
    assert all(k in rest for k in keys), (keys, sent)  # each keyframe, in the motion's order


keyframe = st.fixed_dictionaries(
    {
        "pose": st.fixed_dictionaries(
            {}, optional={n: st.floats(s["min"], s["max"], allow_nan=False) for n, s in JOINTS.items()}
        ),
        "profile": st.sampled_from(["minjerk", "linear"]),
    }
)


@settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(frames=st.lists(keyframe, min_size=1, max_size=4), gaps=st.lists(st.floats(0.05, 0.15), min_size=4, max_size=4))
def test_played_commands_stay_within_limits_and_turn_only_at_keyframes(
    frames: list[dict[str, Any]], gaps: list[float]
) -> None:
    time = 0.0
    for frame, gap in zip(frames, gaps, strict=False):
        time += gap
        frame["time"] = round(time, 6)
    data = motion(*frames)
    rig = make_rig()
    since = play_on(rig, data)
    check_played(rig, since, load_motion(data))


def test_an_angle_too_big_for_a_float_is_refused_as_outside_the_limits() -> None:
    description = load_description({"lines": {"upper": {"port": "sim://unopened"}}, "joints": {"neck": JOINTS["neck"]}})
    with pytest.raises(InvalidArgument, match="outside its limits"):
        description.check_pose({"neck": 10**400})


def test_save_and_load_round_trip(tmp_path: Path) -> None:
    original = load_motion(motion({"time": 1.0, "pose": {"neck": 5}}, {"time": 2, "pose": {}, "profile": "linear"}))
    save_motion(original, tmp_path / "out.json")
    assert load_motion(tmp_path / "out.json") == original
    assert json.loads((tmp_path / "out.json").read_text())["version"] == 1


BAD: list[tuple[Any, str, str]] = [
    ({"version": 1, "keyframes": []}, "format", "must be 'ics35-motion'"),
    (motion({"time": 1, "pose": {}}, version=2) | {"version": 2}, "version", "newer"),
    (motion(), "keyframes", "non-empty list"),
    (motion({"time": 0, "pose": {}}), "keyframes[0].time", "above 0"),
    (motion({"time": 1, "pose": {}}, {"time": 1, "pose": {}}), "keyframes[1].time", "after 1"),
    (motion({"time": "1", "pose": {}}), "keyframes[0].time", "number of seconds"),
    (motion({"time": 1, "pose": {"neck": "up"}}), "keyframes[0].pose.neck", "number of degrees"),
    # A whole number too big for a float (JSON has no limit): refused as any other, not an OverflowError.
    (motion({"time": 10**400, "pose": {}}), "keyframes[0].time", "number of seconds"),
    (motion({"time": 1, "pose": {"neck": -(10**400)}}), "keyframes[0].pose.neck", "number of degrees"),
    # A finite number, but no motion: one that far never ends while it looks as if it runs (its joints creep).
    (motion({"time": 1e308, "pose": {}}), "keyframes[0].time", "at most 3600 seconds"),
    (motion({"time": 1, "pose": {}}, {"time": 3600.5, "pose": {}}), "keyframes[1].time", "at most 3600 seconds"),
    (motion({"time": float("nan"), "pose": {}}), "keyframes[0].time", "number of seconds, not nan"),
    (motion({"time": float("inf"), "pose": {}}), "keyframes[0].time", "number of seconds, not inf"),
    (motion({"time": -1, "pose": {}}), "keyframes[0].time", "above 0"),
    (motion({"time": True, "pose": {}}), "keyframes[0].time", "number of seconds"),
    (motion({"time": 1, "pose": {"neck": float("nan")}}), "keyframes[0].pose.neck", "number of degrees, not nan"),
    (motion({"time": 1, "pose": {"neck": float("-inf")}}), "keyframes[0].pose.neck", "number of degrees, not -inf"),
    (motion({"time": 1, "pose": {}, "profile": "cubic"}), "keyframes[0].profile", "minjerk, linear"),
    (motion({"time": 1, "pose": {}, "speed": 3}), "keyframes[0].speed", "unknown key"),
    (motion({"time": 1, "pose": {}}, loop=True), "loop", "unknown key"),
]


@pytest.mark.parametrize(("data", "key", "phrase"), BAD, ids=[f"{b[1]}-{k}" for k, b in enumerate(BAD)])
def test_each_format_mistake_names_the_file_and_key(tmp_path: Path, data: Any, key: str, phrase: str) -> None:
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(data))
    with pytest.raises(MotionError) as caught:
        load_motion(path)
    assert str(caught.value).startswith(f"{path}: {key}: ") and phrase in str(caught.value)
    assert isinstance(caught.value, InvalidArgument)


@pytest.mark.parametrize(
    ("keyframes", "phrase"),
    [
        ((Keyframe(1e308, {"neck": 5.0}),), r"keyframes\[0\]\.time: 1e\+308 .*at most 3600 seconds"),
        ((Keyframe(float("nan"), {"neck": 5.0}),), r"keyframes\[0\]\.time: must be a number of seconds, not nan"),
        ((Keyframe(0.0, {"neck": 5.0}),), r"keyframes\[0\]\.time: 0 must be above 0"),
        ((Keyframe(1.0, {"neck": 5.0}), Keyframe(0.5, {"neck": 0.0})), r"keyframes\[1\]\.time: 0\.5 must be after 1"),
        ((Keyframe(1.0, {"neck": float("inf")}),), r"keyframes\[0\]\.pose\.neck: must be a number of degrees"),
        ((Keyframe(1.0, {"neck": 5.0}, "cubic"),), r"keyframes\[0\]\.profile: must be one of minjerk, linear"),
        ((), "at least one keyframe"),
    ],
)
def test_a_motion_built_in_python_is_held_to_the_files_rules(keyframes: tuple[Keyframe, ...], phrase: str) -> None:
    # parse_motion checked a file's keyframes, but a Motion built from Keyframes was played as it was: a time of 0
    # threw the joint to its pose at full speed, one of 1e308 never ended.
    with pytest.raises(InvalidArgument, match=phrase):
        Motion(keyframes)


def test_not_json_and_missing_files(tmp_path: Path) -> None:
    (tmp_path / "x.json").write_text("{nope")
    with pytest.raises(MotionError, match="not valid JSON"):
        load_motion(tmp_path / "x.json")
    (tmp_path / "x.json").write_text("[" * 100_000)  # deeper than Python's parser goes: no RecursionError
    with pytest.raises(MotionError, match="not valid JSON: nested too deeply"):
        load_motion(tmp_path / "x.json")
    with pytest.raises(MotionError, match="no such file"):
        load_motion(tmp_path / "y.json")
    # robot.play(5) raised TypeError from pathlib ("expected str, bytes or os.PathLike object").
    for source in (5, None, [{"time": 1}]):
        with pytest.raises(InvalidArgument, match="a motion is"):
            load_motion(source)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("data", "phrase"),
    [
        (motion({"time": 1, "pose": {"neck": 10}}, {"time": 2, "pose": {"hip": 45}}), r"keyframes\[1\]: .*hip: 45"),
        (motion({"time": 1, "pose": {"tail": 10}}), r"keyframes\[0\]: unknown joint\(s\): tail"),
    ],
)
def test_a_motion_outside_the_robot_moves_nothing(data: Any, phrase: str) -> None:
    rig = make_rig()
    with pytest.raises(MotionError, match=phrase):
        play_on(rig, data)
    for spec in JOINTS.values():
        assert targets_sent(rig.sim(spec["line"]), spec["id"]) == []


def test_a_motion_file_outside_the_robot_is_named_in_the_error(tmp_path: Path) -> None:
    # A robot builder's finding: `robot.play("walk.json")` of a file for another robot said "motion: keyframes[0]:
    # unknown joint(s) ...", not which file, as ics35 play and load_motion do.
    path = tmp_path / "walk.json"
    path.write_text(json.dumps(motion({"time": 1, "pose": {"tail": 10}})))
    rig = make_rig()
    with pytest.raises(MotionError) as caught:
        play_on(rig, str(path))
    assert str(caught.value).startswith(f"{path}: keyframes[0]: unknown joint(s): tail"), caught.value


def test_a_safety_stop_reaches_plays_caller() -> None:
    rig = make_rig(safety={"max_current": 20, "action": "free"})
    data = motion({"time": 2.0, "pose": {"knee": -90.0}}, {"time": 4.0, "pose": {"knee": 0.0}})

    async def main(robot: Robot) -> None:
        async with anyio.create_task_group() as tasks:
            tasks.start_soon(robot.play, data)
            async with robot.stream() as stream:
                while (await stream.next_frame()).targets["knee"] is None:
                    pass
            rig.servo("knee").load = 50

    async def run() -> None:
        with anyio.fail_after(GUARD):
            async with open_robot(rig.description, **FAST) as robot:
                await main(robot)

    try:
        with pytest.raises(SafetyStop, match="joint knee"):
            anyio.run(run)
    finally:
        rig.close()
    assert rig.servo("knee").free


@pytest.mark.parametrize("speed", [0, 0.02, 20, 500, float("nan"), "fast"])
def test_a_bad_speed_is_refused_in_words_about_a_time_scale(speed: Any) -> None:
    # speed scales time (2: twice as fast): its error spoke of seconds.
    data = motion({"time": 1, "pose": {"neck": 5}})
    with pytest.raises(InvalidArgument, match="speed") as refused:
        play_on(make_rig(), data, speed=speed)
    assert "seconds" not in str(refused.value) and "twice as fast" in str(refused.value), refused.value


def test_a_motion_slowed_past_an_hour_is_refused_before_anything_is_sent() -> None:
    # A motion's keyframes are held to an hour, but played at speed 0.01 a 3600 s one lasted a hundred hours: its
    # joints crept too slowly to see, the robot's motion taken.  At that speed it is the slip a keyframe's is.
    rig = make_rig()
    data = motion({"time": 0.2, "pose": {"neck": 5}}, {"time": 3600, "pose": {"neck": 6}})
    with pytest.raises(InvalidArgument, match=r"at speed 0\.5, keyframes\[1\]\.time: 7200 must be at most 3600"):
        play_on(rig, data, speed=0.5)
    for spec in JOINTS.values():
        assert targets_sent(rig.sim(spec["line"]), spec["id"]) == []


def test_saving_over_a_link_writes_through_it_and_keeps_the_files_mode(tmp_path: Path) -> None:
    # A motion kept in a shared folder and linked from the robot's: the link stays a link, its target
    # gets the new motion, and the file's permissions are the ones it had.
    motion_a = load_motion(motion({"time": 1.0, "pose": {"neck": 5}}))
    motion_b = load_motion(motion({"time": 1.0, "pose": {"neck": -5}}))
    real = tmp_path / "shared" / "wave.json"
    real.parent.mkdir()
    save_motion(motion_a, real)
    real.chmod(0o640)
    link = tmp_path / "wave.json"
    link.symlink_to(real)
    backup = save_motion(motion_b, link)
    assert link.is_symlink() and load_motion(real) == motion_b
    assert backup is not None and load_motion(backup) == motion_a
    assert real.stat().st_mode & 0o777 == 0o640


def test_a_looping_play_gives_up_the_joints_another_command_takes_over() -> None:
    # A newer move_to of a joint a looping play drives: the play's next pass took the joint back, and the
    # move_to returned at once without reaching its pose.  The loop goes on with its other joints.
    rig = make_rig()
    data = motion(
        {"time": 0.1, "pose": {"neck": 20.0, "hip": 10.0}}, {"time": 0.2, "pose": {"neck": -20.0, "hip": -10.0}}
    )

    async def main() -> tuple[float, dict[str, int]]:
        with anyio.fail_after(GUARD):
            async with open_robot(rig.description, **FAST) as robot, anyio.create_task_group() as tasks:
                tasks.start_soon(lambda: robot.play(data, loop=True))
                await anyio.sleep(0.3)  # a pass or more under way
                await robot.move_to({"neck": 45.0}, duration=0.3)
                mark = {"upper": rig.upper.transactions, "lower": rig.lower.transactions}
                await anyio.sleep(0.5)  # the loop's later passes
                reached = robot.targets["neck"]
                tasks.cancel_scope.cancel()
                return reached, mark

    try:
        reached, mark = anyio.run(main)
    finally:
        rig.close()
    assert reached == 45.0
    neck = targets_sent(rig.upper, JOINTS["neck"]["id"], mark["upper"])
    assert set(neck) == {sent_position(JOINTS["neck"], 45.0)}, neck  # the loop left the neck where it went
    hip = targets_sent(rig.lower, JOINTS["hip"]["id"], mark["lower"])
    assert len(set(hip)) > 2  # and still moves the hip


def test_a_motion_that_cannot_be_written_leaves_the_file_and_its_backup_as_they_were(tmp_path: Path) -> None:
    # The disk fills up (here: a file size limit) while a motion is saved over an older one that already has
    # a backup: the motion file was kept whole, but its backup was truncated by the copy that failed.
    target, backup = tmp_path / "wave.json", tmp_path / "wave.json.bak"
    target.write_text(json.dumps({"format": "ics35-motion", "version": 1, "keyframes": [], "pad": "x" * 400}))
    backup.write_text("the motion as it was two saves ago\n")
    before = {path.name: path.read_bytes() for path in (target, backup)}
    resource = pytest.importorskip("resource")  # (a file size limit for one child process: POSIX)
    script = (
        "import sys; from ics35_async.robot import Keyframe, Motion, save_motion\n"
        "try:\n"
        f"    save_motion(Motion((Keyframe(1.0, {{'neck': 10.0}}),)), {str(target)!r})\n"
        "except OSError as exc:\n"
        "    sys.exit(f'OSError {exc.errno}')\n"
    )

    def small_files_only() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (100, 100))  # (Python ignores SIGXFSZ: writes fail, EFBIG)

    proc = subprocess.run([sys.executable, "-c", script], preexec_fn=small_files_only, capture_output=True, text=True)
    assert proc.returncode == 1 and "OSError" in proc.stderr, proc.stderr
    assert {path.name: path.read_bytes() for path in (target, backup)} == before
    assert sorted(path.name for path in tmp_path.iterdir()) == ["wave.json", "wave.json.bak"]  # nothing half-written


def test_a_backup_path_that_is_a_directory_is_named_in_the_error(tmp_path: Path) -> None:
    # It said "Is a directory" of the motion's own path.
    target = tmp_path / "wave.json"
    target.write_text("{}\n")
    (tmp_path / "wave.json.bak").mkdir()
    with pytest.raises(IsADirectoryError) as caught:
        save_motion(Motion((Keyframe(1.0, {"neck": 10.0}),)), target)
    assert caught.value.filename == str(tmp_path / "wave.json.bak")
    assert "wave.json.bak, which is a directory" in str(caught.value)
    assert target.read_text() == "{}\n" and sorted(p.name for p in tmp_path.iterdir()) == ["wave.json", "wave.json.bak"]


def test_files_from_an_editor_that_writes_a_byte_order_mark_read(tmp_path: Path) -> None:
    # Notepad's "UTF-8 with BOM": the file was refused as "not valid JSON" (as "not valid TOML: Invalid
    # statement (at line 1, column 1)" for a robot file), for a mark the editor does not show.
    wave = tmp_path / "wave.json"
    wave.write_bytes(b"\xef\xbb\xbf" + json.dumps(motion({"time": 1.0, "pose": {"neck": 5}})).encode())
    assert load_motion(wave).keyframes[0].pose == {"neck": 5}
    robot = tmp_path / "robot.toml"
    robot.write_bytes(
        b'\xef\xbb\xbf[lines.main]\r\nport = "sim://"\r\n\r\n[joints.neck]\r\nline = "main"\r\nid = 1\r\n'
    )
    assert list(load_description(robot).joints) == ["neck"]


@pytest.mark.parametrize("backend", ["asyncio", "trio"])
def test_a_stop_between_two_passes_of_a_looping_play_ends_the_loop(backend: str) -> None:
    # A stop() that came as one pass ended, before the play had started the next: there was no motion to stop,
    # stop() returned, and the next pass then started, moving the neck after the stop.
    rig = make_rig()
    data = motion({"time": 0.05, "pose": {"neck": 20.0}}, {"time": 0.1, "pose": {"neck": -20.0}})
    outcome: list[BaseException | None] = []

    async def main() -> int:
        with anyio.fail_after(GUARD):
            async with open_robot(rig.description, **FAST) as robot, anyio.create_task_group() as tasks:

                async def player() -> None:
                    try:
                        await robot.play(data, loop=True)
                    except MotionStopped as exc:
                        outcome.append(exc)
                    else:
                        outcome.append(None)

                tasks.start_soon(player)
                # Polled at every turn of the loop, so that the stop comes in the turn the pass ends in.
                while robot.targets["neck"] != -20.0:
                    await anyio.sleep(0)
                await robot.stop(ramp=0.2)
                mark = rig.upper.transactions
                await anyio.sleep(0.3)
                tasks.cancel_scope.cancel()
                return mark

    try:
        mark = anyio.run(main, backend=backend)
    finally:
        rig.close()
    neck = targets_sent(rig.upper, JOINTS["neck"]["id"], mark)
    assert set(neck) == {sent_position(JOINTS["neck"], -20.0)}, sorted(set(neck))
    assert outcome and isinstance(outcome[0], MotionStopped), outcome


def test_a_pose_given_where_a_motion_is_wanted_is_told_to_go_to_move_to() -> None:
    # `robot.play({"base": 10})`: "unknown key (known: format, version, ...)", and no word of the pose it was.
    with pytest.raises(MotionError) as caught:
        parse_motion({"base": 10.0})
    assert "a pose, not a motion" in str(caught.value) and "move_to" in str(caught.value), str(caught.value)
