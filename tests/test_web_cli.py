"""``ics35 web`` as a user starts it: the URL on stdout's first line, the simulator named, --listen,
the token from the environment or a file, Ctrl-C, and the missing extra, all without a traceback."""

from __future__ import annotations

import base64
import json
import os
import signal
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest

from ics35_async.extras import install_command, installed_from
from tests.support.cli_runs import PRESS_AT_A_CALL
from tests.support.pty_line import PtyLine
from tests.support.timing import scaled


@contextmanager
def web(
    *args: str,
    env: dict[str, str] | None = None,
    ignoring_sigint: bool = False,
    python: tuple[str, ...] = ("-m", "ics35_async.cli"),
) -> Iterator[tuple[subprocess.Popen[str], str]]:
    """``ics35 web``; ``ignoring_sigint``: started as a script's background job is, SIGINT ignored; ``python``:
    Python's arguments before the command's (a ``-c`` program and its own, to run it another way)."""
    environment = {k: v for k, v in os.environ.items() if k not in ("ICS35_PORT", "ICS35_WEB_TOKEN")}
    proc = subprocess.Popen(
        [sys.executable, *python, "web", "--no-browser", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**environment, **(env or {})},
        preexec_fn=(lambda: signal.signal(signal.SIGINT, signal.SIG_IGN)) if ignoring_sigint else None,
    )
    assert proc.stdout is not None
    url = proc.stdout.readline().strip()
    try:
        yield proc, url
    finally:
        if proc.poll() is None:
            proc.terminate()
        proc.wait(10)
        assert proc.stdout is not None and proc.stderr is not None
        proc.stdout.close()
        proc.stderr.close()


def get(url: str, token: str | None = None) -> tuple[int, Any]:
    request = urllib.request.Request(url, headers={"cookie": f"ics35_token={token}"} if token else {})
    try:
        with urllib.request.urlopen(request, timeout=10) as response:
            return response.status, json.loads(response.read())
    except urllib.error.HTTPError as exc:
        return exc.code, exc.read().decode()


def post(url: str, token: str, data: Any) -> tuple[int, Any]:
    headers = {"cookie": f"ics35_token={token}", "content-type": "application/json"}
    request = urllib.request.Request(url, data=json.dumps(data).encode(), headers=headers, method="POST")
    try:
        with urllib.request.urlopen(request, timeout=10) as response:
            return response.status, json.loads(response.read())
    except urllib.error.HTTPError as exc:
        return exc.code, json.loads(exc.read())


def split(url: str) -> tuple[str, str]:
    base, _, token = url.partition("/?token=")
    return base, token


def test_the_url_comes_first_and_the_default_port_is_the_simulator_said_so() -> None:
    with web() as (proc, url):
        base, token = split(url)
        assert base.startswith("http://127.0.0.1:") and len(token) >= 20
        status, body = get(f"{base}/api/status", token)
        assert status == 200 and body["simulator"] is True and body["connected"] is True
        assert get(f"{base}/api/status")[0] == 401
        proc.send_signal(signal.SIGINT)  # Ctrl-C
        assert proc.wait(10) == 0
        assert proc.stderr is not None
        err = proc.stderr.read()
    assert "built-in simulator" in err and "Traceback" not in err
    assert err.count("no --port given") == 1 and "for hardware: --port /dev/ttyUSB0" in err, err


def test_without_port_the_simulators_servos_answer_at_the_baud_rate_given() -> None:
    # As every command's: the built-in simulator stands in for servos set up for the line (they answered only at
    # 115200, and the page opened on a line where none did).
    with web("--baud", "625000") as (_, url):
        base, token = split(url)
        status, body = get(f"{base}/api/status", token)
        assert status == 200 and body["baud"] == 625000 and body["connected"] is True, body
        status, servo = get(f"{base}/api/servo/1/eeprom", token)
        rate = next(field["value"] for field in servo["fields"] if field["name"] == "baud_rate")
        assert status == 200 and rate == 625000, servo


def page_socket(base: str, token: str) -> socket.socket:
    """A page's WebSocket, open (as a browser tab keeps one); it never answers the server's close."""
    host, port = base.removeprefix("http://").rsplit(":", 1)
    page = socket.create_connection((host, int(port)))
    key = base64.b64encode(os.urandom(16)).decode()
    page.sendall(
        f"GET /ws?page=p1 HTTP/1.1\r\nHost: {host}:{port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
        f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\nOrigin: {base}\r\n"
        f"Cookie: ics35_token={token}\r\n\r\n".encode()
    )
    assert page.recv(100).startswith(b"HTTP/1.1 101"), "no WebSocket"
    return page


def request_under_way(base: str, token: str, path: str, body: bytes | None = None) -> socket.socket:
    """A request sent, its answer not read (the server is still answering it): a GET, or with ``body`` a POST of it
    as JSON, as the page sends a change."""
    host, port = base.removeprefix("http://").rsplit(":", 1)
    asking = socket.create_connection((host, int(port)))
    head = f"Host: {host}:{port}\r\nCookie: ics35_token={token}\r\n"
    if body is None:
        asking.sendall(f"GET {path} HTTP/1.1\r\n{head}\r\n".encode())
    else:
        sent = f"Content-Type: application/json\r\nContent-Length: {len(body)}\r\n"
        asking.sendall(f"POST {path} HTTP/1.1\r\n{head}{sent}\r\n".encode() + body)
    return asking


def answer_of(asking: socket.socket) -> bytes:
    """Everything the server sent on ``asking`` until it closed it."""
    asking.settimeout(scaled(10))
    answer = b""
    while chunk := asking.recv(4096):
        answer += chunk
    return answer


@pytest.mark.parametrize("asked", ["a read", "a scan", "a change"])
def test_a_second_ctrl_c_stops_the_server_at_once_saying_what_it_cut_short(asked: str) -> None:
    # A stop waits for what the server is still answering (here a read of a servo that is not there, asked at
    # every rate with a long --timeout: a dozen seconds); a second Ctrl-C was taken for the same stop, and the
    # person had no way out but kill -9.  As every command's, it now quits at once: what was still being
    # answered is cut short, the servos are left as the stop leaves them, and the last line says so.  The
    # request cut short was answered "500 Internal Server Error", a fault of the server where the person stopped
    # it: it is answered 503 with the reason in plain words, and nothing is logged about it.
    with web("--port", "sim://?ids=1", "--timeout", "2") as (proc, url):
        base, token = split(url)
        page = page_socket(base, token)
        if asked == "a read":
            asking = request_under_way(base, token, "/api/servo/5/eeprom")
        elif asked == "a scan":  # (a POST that only reads: 625000 baud's silent ID read alone takes 2 s)
            asking = request_under_way(base, token, "/api/scan", b"{}")
        else:  # (Many servos' Apply: servo 1 written at once, then absent IDs 2-31 each waited for)
            change = {"ids": list(range(1, 32)), "changes": {"damping": 37}}
            asking = request_under_way(base, token, "/api/many/apply", json.dumps(change).encode())
        time.sleep(0.5)  # (under way: the server has it)
        proc.send_signal(signal.SIGINT)  # Ctrl-C
        time.sleep(0.5)
        proc.send_signal(signal.SIGINT)  # and again: now
        try:
            answer = answer_of(asking)
            code = proc.wait(scaled(10))  # (the request alone would hold it a dozen seconds; the line ends its
            # transaction on the wire first, a --timeout at most)
        finally:
            page.close()
            asking.close()
        assert proc.stderr is not None
        err = proc.stderr.read()
    assert code == 130, err
    assert "Traceback" not in err and "Exception" not in err, err
    last = err.strip().splitlines()[-1]
    assert last.startswith("error: interrupted: Ctrl-C again stopped the server at once"), err
    assert "cut short" in last and "every servo's torque left as it was" in last, err
    head, _, body = answer.partition(b"\r\n\r\n")
    assert head.startswith(b"HTTP/1.1 503 "), answer
    assert b"content-type: text/plain" in head.lower(), answer
    if asked != "a change":
        assert body == b"the server is stopping", answer
    else:
        # A change cut short part-way said only "the server is stopping", as if refused: servo 1 had been written.
        assert body.startswith(b"the server stopped while doing this: it may be done in part"), answer


@pytest.mark.parametrize("gap", [0.05, 0.3, 0.4, 0.5])
def test_a_second_ctrl_c_with_nothing_left_to_wait_for_is_the_same_stop(gap: float) -> None:
    # Only pages open: the stop ends them at once, and a double press, as a person types it, ends as one does
    # (one landing as the process ended killed it by SIGINT, not with its exit code).
    with web() as (proc, url):
        base, token = split(url)
        page = page_socket(base, token)
        proc.send_signal(signal.SIGINT)  # Ctrl-C
        time.sleep(gap)
        proc.send_signal(signal.SIGINT)  # and again, at once, as the server stops
        code = proc.wait(10)
        page.close()
        assert proc.stderr is not None
        err = proc.stderr.read()
    assert code == 0 and "Traceback" not in err and "Exception" not in err and "error" not in err, err


# A double Ctrl-C's second press landing as asyncio's runner closes the server's loop, the stop made (a profile
# hook presses at the named call of the runner's close): inside uvloop's own step (its self-pipe's socket closed
# as a run of the loop ends) Python's handler, back by then, raised KeyboardInterrupt, which left the loop running
# and unclosable: "RuntimeError: Cannot close a running event loop", a traceback, exit code 1.
_SECOND_PRESS_AS_THE_LOOP_CLOSES = (
    PRESS_AT_A_CALL
    + """
import asyncio, atexit
from ics35_async.cli import main

close = asyncio.Runner.close

def closing(self):
    sys.setprofile(press)
    close(self)

asyncio.Runner.close = closing
atexit.register(lambda: print("pressed" if calls[0] >= count else f"{where} was called {calls[0]} times"))
main(sys.argv[3:])
"""
)


@pytest.mark.parametrize(
    ("loop", "where"),
    [
        ("uvloop", ("_decref_socketios", 1)),
        ("uvloop", ("_real_close", 1)),
        ("uvloop", ("_real_close", 2)),
        ("asyncio", ("shutdown_asyncgens", 1)),
        ("asyncio", ("shutdown_default_executor", 1)),
    ],
    ids=lambda value: value if isinstance(value, str) else f"{value[0]}-{value[1]}",
)
def test_a_second_ctrl_c_as_the_servers_loop_closes_is_the_same_stop(loop: str, where: tuple[str, int]) -> None:
    python = ("-c", _SECOND_PRESS_AS_THE_LOOP_CLOSES, where[0], str(where[1]))
    with web(env={"ICS35_LOOP": loop}, python=python) as (proc, url):
        base, token = split(url)
        assert get(f"{base}/api/status", token)[0] == 200  # (the server runs: the URL comes before it starts)
        proc.send_signal(signal.SIGINT)  # Ctrl-C: the second comes as the runner closes the loop
        code = proc.wait(scaled(10))
        assert proc.stdout is not None and proc.stderr is not None
        out, err = proc.stdout.read(), proc.stderr.read()
    assert out == "pressed\n", out
    assert code == 0 and "Traceback" not in err and "Exception" not in err and "error" not in err, err


def test_a_server_started_ignoring_sigint_keeps_ignoring_it() -> None:
    # `ics35 web &` in a script (or under nohup's kin): the shell starts it with SIGINT ignored, so that the
    # Ctrl-C typed for the script's foreground command is not for it.  The web server turned Ctrl-C back on:
    # that Ctrl-C stopped it too.  SIGTERM still ends it.
    with web(ignoring_sigint=True) as (proc, url):
        base, token = split(url)
        assert get(f"{base}/api/status", token)[0] == 200  # (the server runs: the URL comes before it starts)
        proc.send_signal(signal.SIGINT)
        time.sleep(0.5)  # (a Ctrl-C heard ends it at once: see the test above)
        assert proc.poll() is None, proc.stderr.read() if proc.stderr else ""
        assert get(f"{base}/api/status", token)[0] == 200
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(10) == 143
        assert proc.stderr is not None
        err = proc.stderr.read()
    assert "Traceback" not in err, err


def with_browser(browser: str | None, *args: str, environment: dict[str, str] | None = None) -> tuple[str, str]:
    """``ics35 web`` (stdout's first line, stderr) stopped once it answers, with ``$BROWSER`` the only browser there
    is: no display, no terminal browser (as on a headless machine or across ssh)."""
    gone = ("ICS35_PORT", "ICS35_WEB_TOKEN", "DISPLAY", "WAYLAND_DISPLAY", "TERM", "BROWSER")
    kept = {k: v for k, v in os.environ.items() if k not in gone}
    proc = subprocess.Popen(
        [sys.executable, "-m", "ics35_async.cli", "web", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**kept, **({} if browser is None else {"BROWSER": browser}), **(environment or {})},
    )
    assert proc.stdout is not None and proc.stderr is not None
    try:
        url = proc.stdout.readline().strip()
        base, token = split(url)
        assert get(f"{base}/api/status", token)[0] == 200  # (the server runs, the browser tried before it)
        proc.send_signal(signal.SIGINT)
        assert proc.wait(scaled(10)) == 0
        return url, proc.stderr.read()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        proc.stdout.close()
        proc.stderr.close()


NO_BROWSER_OPENED = "no browser could be opened here: open the address above in one yourself"


@pytest.mark.skipif(sys.platform != "linux", reason="another system has a browser of its own besides $BROWSER")
def test_where_no_browser_can_be_opened_the_command_says_so_once(tmp_path: Path) -> None:
    # A headless machine, an ssh session: the browser fails to open, and the command said nothing of it.
    url, err = with_browser("false")
    assert url.startswith("http://127.0.0.1:") and "/?token=" in url
    assert err.count(NO_BROWSER_OPENED) == 1 and "Traceback" not in err, err
    # A browser that opens: nothing said; it was given the address.
    opened = tmp_path / "opened"
    browser = tmp_path / "browser"
    browser.write_text(f'#!/bin/sh\necho "$1" > {opened}\n')
    browser.chmod(0o755)
    url, err = with_browser(str(browser))
    assert opened.read_text().strip() == url and NO_BROWSER_OPENED not in err, err
    # --no-browser: none tried, and nothing said about it.
    opened.unlink()
    url, err = with_browser(str(browser), "--no-browser")
    assert not opened.exists() and NO_BROWSER_OPENED not in err and url.startswith("http://"), err


@pytest.mark.skipif(sys.platform != "linux", reason="another system has a browser of its own, display or not")
def test_without_a_display_no_terminal_browser_is_started_in_the_commands_terminal(tmp_path: Path) -> None:
    # Across ssh (a terminal, no display) the default browser is a terminal one where installed (www-browser,
    # lynx, w3m): it took the terminal over, the server waiting for it to quit, on a page it cannot run (the
    # configurator's scripts).  None is started: the command says to open the address, as where none is.
    opened = tmp_path / "opened"
    (tmp_path / "www-browser").write_text(f'#!/bin/sh\necho "$1" > {opened}\n')
    (tmp_path / "www-browser").chmod(0o755)
    path = f"{tmp_path}{os.pathsep}{os.environ.get('PATH', '')}"
    url, err = with_browser(None, environment={"TERM": "xterm", "PATH": path})
    assert not opened.exists() and err.count(NO_BROWSER_OPENED) == 1, err
    # $BROWSER names the one to use: it is used, display or not (a person's own choice).
    url, err = with_browser(f"{tmp_path}/www-browser", environment={"TERM": "xterm", "PATH": path})
    assert opened.read_text().strip() == url and NO_BROWSER_OPENED not in err, err


def test_a_token_from_the_environment_or_a_file_is_the_one_asked_for(tmp_path: Path) -> None:
    token = "robot-board-token-1234567890"
    with web(env={"ICS35_WEB_TOKEN": token}) as (_, url):
        base, printed = split(url)
        assert printed == token and get(f"{base}/api/status", token)[0] == 200
    path = tmp_path / "token"
    path.write_text("from-a-file-token-0987654321\n")
    with web("--token-file", str(path)) as (_, url):
        assert split(url)[1] == "from-a-file-token-0987654321"


def test_listening_beyond_loopback_needs_listen_and_warns() -> None:
    with web("--listen", "0.0.0.0:0") as (proc, url):
        base, token = split(url)
        assert get(f"{base}/api/status", token)[0] == 200
        proc.terminate()
        proc.wait(10)
        assert proc.stderr is not None
        assert "warning: serving on 0.0.0.0" in proc.stderr.read()


def test_bad_options_are_refused_in_words(cli: Any, tmp_path: Path) -> None:
    short = tmp_path / "short"
    short.write_text("abc")
    for args, words in (
        (("--listen", "127.0.0.1:99999"), "0..65535"),
        (("--token-file", str(tmp_path / "missing")), "cannot read the token file"),
        (("--token-file", str(short)), "at least 16"),
    ):
        result = cli("web", "--no-browser", *args)
        assert result.code == 2 and words in result.err, result.err
    busy = cli("web", "--no-browser", "--listen", "203.0.113.9:0")  # an address this machine does not have
    assert busy.code == 2 and "cannot listen on 203.0.113.9" in busy.err
    # (it warned "serving on 203.0.113.9: any machine that can reach it ... can move these servos" first)
    assert "serving on" not in busy.err, busy.err
    alone = cli("web", "--no-browser", "--start-pose", "knee=30")
    assert alone.code == 2 and "goes with --robot" in alone.err, alone.err
    yes = cli("web", "--no-browser", "--yes")  # (it frees a robot's joints: nothing else asks in ics35 web)
    assert yes.code == 2 and "--yes frees a robot's ICS 3.5 joints" in yes.err and "goes with --robot" in yes.err
    robot = tmp_path / "arm.toml"
    robot.write_text('[lines.arm]\nport = "sim://web-cli-pose"\n[joints.knee]\nline = "arm"\nid = 1\nmax = 40\n')
    for pose, words in (
        ("hip=10", "--start-pose: unknown joint"),
        ("knee=50", "--start-pose: joint knee"),
        ("knee", "joint=degrees"),
    ):
        refused = cli("web", "--no-browser", "--robot", str(robot), "--start-pose", pose)
        assert refused.code == 2 and words in refused.err, (pose, refused.err)


def test_without_the_web_extra_the_command_says_how_to_install_it(
    cli: Any,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    for name in [m for m in sys.modules if m.startswith(("ics35_async.web", "starlette"))]:
        monkeypatch.delitem(sys.modules, name)
    monkeypatch.setitem(sys.modules, "starlette", None)
    result = cli("web", "--no-browser")
    assert result.code == 2 and install_command("web", installed_from()) in result.err
    # This checkout is installed editable (make .venv/.installed): the hint installs the extra into it.
    if installed_from()[0] == "editable":
        root = Path(__file__).resolve().parent.parent
        assert f"pip install -e '{root}[web]'" in result.err


def test_the_install_hint_fits_how_the_package_was_installed(tmp_path: Path) -> None:
    assert install_command("web", ("editable", tmp_path)) == f"pip install -e '{tmp_path}[web]'"
    assert install_command("plot", ("package", None)) == "pip install 'ics35_async[plot]'"
    either = install_command("web", ("unknown", None))
    assert "pip install 'ics35_async[web]'" in either and "pip install -e '.[web]'" in either
    spaced = tmp_path / "my clone"
    assert install_command("web", ("editable", spaced)) == f"pip install -e '{spaced}[web]'"


def test_listen_takes_host_and_port_in_the_usual_spellings() -> None:
    from ics35_async.web import Listen

    assert Listen.parse("8080") == Listen("127.0.0.1", 8080)
    assert Listen.parse(":8080") == Listen("127.0.0.1", 8080)
    assert Listen.parse("0.0.0.0:80") == Listen("0.0.0.0", 80)
    assert Listen.parse("[::1]:9000") == Listen("::1", 9000)
    assert Listen.parse("localhost").loopback and not Listen.parse("192.168.1.5:80").loopback


def test_a_robot_line_on_a_fast_simulator_without_a_rate_is_said_to_run_flat_out(tmp_path: Path) -> None:
    # Such a line's stream runs as fast as the CPU allows, in the server's own loop: its pages answered
    # slowly (seconds) and nothing said why.  A rate, or a real-time simulator, paces it.
    robot = tmp_path / "arm.toml"
    robot.write_text(
        '[lines.fast]\nport = "sim://web-cli-fast?ids=1"\n[lines.paced]\nport = "sim://web-cli-paced?ids=1"\n'
        'rate_hz = 100\n[lines.real]\nport = "sim://web-cli-real?ids=1&realtime=1"\n'
        '[joints.a]\nline = "fast"\nid = 1\n[joints.b]\nline = "paced"\nid = 1\n[joints.c]\nline = "real"\nid = 1\n'
    )
    with web("--robot", str(robot)) as (proc, url):
        base, token = split(url)
        assert get(f"{base}/api/status", token)[0] == 200  # (the server has started: the robot is open)
        proc.send_signal(signal.SIGINT)
        assert proc.wait(10) == 0
        assert proc.stderr is not None
        err = " ".join(proc.stderr.read().split())
    assert "robot line fast (sim://web-cli-fast?ids=1) is a fast simulator with no rate_hz" in err, err
    # Said of that line alone.  (Not "line real" anywhere: on a loaded machine the real-time line's limits read
    # can time out on the default allowance, and its own warning names the line.)
    assert err.count("is a fast simulator") == 1, err
    assert "robot line paced" not in err and "robot line real" not in err, err


@pytest.mark.pty
@pytest.mark.parametrize("yes", [False, True], ids=["asks", "yes"])
def test_the_server_frees_a_standing_robots_ics35_joints_at_its_start_only_with_yes(tmp_path: Path, yes: bool) -> None:
    # It freed them without a word as it started, before any page was open: a humanoid standing on them fell.
    line = PtyLine((1,))
    try:
        line.sim.servo(1).command_position(7000)  # (bearing the robot)
        robot = tmp_path / "arm.toml"
        robot.write_text(f'[lines.arm]\nport = "{line.path}"\n[joints.shoulder]\nline = "arm"\nid = 1\n')
        with web("--robot", str(robot), *(["--yes"] if yes else [])) as (proc, url):
            base, token = split(url)
            assert get(f"{base}/api/robot", token)[1]["open"] is yes  # (the server has started: the open is over)
            freed_at_start = line.sim.servo(1).free
            if not yes:  # the page's answer opens it: the terminal, which said it was not open, says so too
                assert post(f"{base}/api/robot/reopen", token, {"start_free": ["shoulder"]})[1]["open"]
            proc.send_signal(signal.SIGINT)
            assert proc.wait(10) == 0
            assert proc.stderr is not None, proc.stdout
            err = " ".join(proc.stderr.read().split())
            out = " ".join(proc.stdout.read().split()) if proc.stdout is not None else ""
        assert freed_at_start is yes, err
        said = "the robot was not opened, nothing freed: joint shoulder speaks ICS 3.5"
        assert (said in err and "answer the question on the Robot page" in err) is not yes, err
        opened = "the Robot page's answer opened the robot: shoulder freed to read where it stands"
        assert (opened in err + out) is not yes, (err, out)
        # Ctrl-C said nothing of what the server left the robot in (it leaves every joint as it is)
        left = "the server leaves the robot's joints as they are: joint shoulder was freed to read where it stands"
        assert left in err + out, (err, out)
    finally:
        line.close()


@pytest.mark.pty
def test_the_terminal_says_when_a_lost_line_stops_the_robot(tmp_path: Path) -> None:
    # The page said so; the terminal, which had said how the robot opened, said nothing.
    line = PtyLine((1,))
    try:
        robot = tmp_path / "arm.toml"
        robot.write_text(f'[lines.arm]\nport = "{line.path}"\n[joints.shoulder]\nline = "arm"\nid = 1\n')
        with web("--robot", str(robot), "--yes") as (proc, url):
            base, token = split(url)
            assert get(f"{base}/api/robot", token)[1]["open"]
            line.sim.unplug()
            deadline = time.monotonic() + scaled(10.0)
            while get(f"{base}/api/robot", token)[1]["error"] is None:
                assert time.monotonic() < deadline, "the robot never said it stopped"
                time.sleep(0.05)
            proc.send_signal(signal.SIGINT)
            assert proc.wait(10) == 0
            assert proc.stderr is not None and proc.stdout is not None
            said = " ".join((proc.stderr.read() + proc.stdout.read()).split())
        assert f"the robot stopped: line arm ({line.path}) lost its port" in said, said
        assert "press Reconnect on the Robot page" in said, said
    finally:
        line.close()


@contextmanager
def silent_page(base: str, token: str, page: str) -> Iterator[None]:
    """A page named ``page`` whose WebSocket opens, then reads nothing and answers nothing (its network went:
    its socket stays open)."""
    host, port = base.removeprefix("http://").split(":")
    key = base64.b64encode(os.urandom(16)).decode()
    with socket.create_connection((host, int(port)), timeout=10) as ws:
        ws.sendall(
            f"GET /ws?page={page} HTTP/1.1\r\nHost: {host}:{port}\r\nUpgrade: websocket\r\n"
            f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n"
            f"Origin: {base}\r\nCookie: ics35_token={token}\r\n\r\n".encode()
        )
        assert ws.recv(4096).startswith(b"HTTP/1.1 101"), "the page's WebSocket was refused"
        yield


def switched_off_once_silent(base: str, token: str, page: str, switch: tuple[str, str], state: tuple[str, str]) -> None:
    """``page`` (a :func:`silent_page`) switches motion on at ``switch`` (a path, and the key of its answer
    saying it is on); returns once the server's ``state`` (the same) says it went off: the page answered no
    pings."""
    switch_path, switched = switch
    status, answer = post(f"{base}{switch_path}", token, {"enabled": True, "page": page})
    assert status == 200 and answer[switched] is True, answer
    path, key = state
    deadline = time.monotonic() + scaled(8.0)
    while get(f"{base}{path}", token)[1][key]:
        assert time.monotonic() < deadline, f"motion stayed on ({path}) for a page that answers nothing"
        time.sleep(0.1)


def test_motion_a_page_switched_on_goes_off_once_its_network_is_gone() -> None:
    # A page whose network went (a laptop asleep, Wi-Fi gone) closes nothing: the server hears nothing more
    # from it, and its motion stayed on for the next page, tab or script to find.  The server's pings go
    # unanswered: within seconds the page is gone, its motion off.
    with web("--port", "sim://?ids=1") as (_, url):
        base, token = split(url)
        page = "a-page-whose-network-went"
        with silent_page(base, token, page):
            switched_off_once_silent(
                base, token, page, ("/api/servo/1/motion", "enabled"), ("/api/status", "motion_on")
            )
            status, refused = post(f"{base}/api/servo/1/move", token, {"position": 8000})
            assert status == 409 and "page" in refused["error"], refused


def test_the_robots_motion_a_page_switched_on_goes_off_once_its_network_is_gone(tmp_path: Path) -> None:
    # As for the Servo page: the Robot page's "enable motion" stayed on for the next page, tab or script.
    robot = tmp_path / "arm.toml"
    robot.write_text(
        '[lines.arm]\nport = "sim://web-cli-silent?ids=1"\nrate_hz = 100\n'
        '[joints.knee]\nline = "arm"\nid = 1\nmax = 40\n'
    )
    with web("--robot", str(robot)) as (_, url):
        base, token = split(url)
        page = "a-robot-page-whose-network-went"
        with silent_page(base, token, page):
            switched_off_once_silent(
                base, token, page, ("/api/robot/motion", "motion_enabled"), ("/api/robot", "motion_enabled")
            )
            status, refused = post(f"{base}/api/robot/move", token, {"pose": {"knee": 20}})
            assert status == 409 and "enable motion" in refused["error"], refused
