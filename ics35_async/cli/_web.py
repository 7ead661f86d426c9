"""``ics35 web``: serve the servo configurator to a browser (the ``web`` extra; imported only when run)."""

from __future__ import annotations

import sys

import click
from rich.markup import escape

from ..errors import InvalidArgument
from ..extras import extra_hint
from ..terminal import clear_after_ctrl_c
from ..transports.wire_device import example_port
from ._common import CliError, ExitCode, settings_of
from ._console import say, say_labelled
from ._loop import loop_factory, quiet_executor_shutdown
from ._signals import same_stop_for_a_moment
from ._start_pose import parse_start_pose, start_pose_option


@click.command()
@click.option(
    "--listen",
    metavar="HOST:PORT",
    default="127.0.0.1:0",
    show_default=True,
    help="Address to serve on (port 0: a free one). Anything but loopback lets other machines reach the page.",
)
@click.option("--no-browser", is_flag=True, help="Do not open the default browser (print the URL only).")
@click.option(
    "--token-file",
    metavar="FILE",
    help="Read the access token from FILE (default: $ICS35_WEB_TOKEN, else a new random one).",
)
@click.option(
    "--robot",
    "robot_file",
    metavar="ROBOT.toml",
    help="Also serve a Robot page for this robot description (its lines are its own; see ics35 play).",
)
@start_pose_option
@click.option(
    "--yes",
    "-y",
    is_flag=True,
    help="With --robot: free its ICS 3.5 joints at the start to read them, without the Robot page's question.",
)
@click.pass_context
def web(
    ctx: click.Context,
    listen: str,
    no_browser: bool,
    token_file: str | None,
    robot_file: str | None,
    start_pose_text: str | None,
    yes: bool,
) -> int:
    """Serve the servo configurator in the browser: scan, EEPROM, backup, renumber, jog, live plots, traffic.

    Prints the page's URL (with its access token) on the first line of stdout.
    Without --port it serves the built-in simulator, labelled as such on every page.
    With --robot on a serial line, ICS 3.5 joints that would start free (read by freeing them) wait for the
    Robot page's question before the robot opens (--start-pose states where they stand instead; --yes frees them).
    """
    settings = settings_of(ctx)
    start_pose = parse_start_pose(start_pose_text)
    if start_pose is not None and robot_file is None:
        raise click.UsageError("--start-pose is where a robot stands: it goes with --robot ROBOT.toml")
    if yes and robot_file is None:
        raise click.UsageError("--yes frees a robot's ICS 3.5 joints at the start: it goes with --robot ROBOT.toml")
    try:
        from ..web import LineConfig, Listen, load_token, serve
    except ImportError as exc:
        raise CliError(
            ExitCode.USAGE,
            f"ics35 web needs the web extra ({exc.name} is missing)",
            f"install it with: {extra_hint('web')}",
        ) from None
    loop, _ = loop_factory()  # (ICS35_LOOP, as for every command; a bad one refused before anything is bound)
    try:
        where = Listen.parse(listen)
        token = load_token(token_file)
    except InvalidArgument as exc:
        raise click.BadParameter(str(exc), param_hint="--listen" if "listen" in str(exc) else "--token-file") from None
    line_from_robot = settings.port_defaulted and robot_file is not None
    if line_from_robot:
        say_labelled(
            "[dim]note:[/dim]", "[dim]no --port given: the pages work on the robot's first line once it is open[/dim]"
        )
    elif settings.port_defaulted:
        say_labelled(
            "[dim]note:[/dim]",
            "[dim]no --port given: the page serves the built-in simulator "
            f"(for hardware: --port {example_port()})[/dim]",
        )
    config = LineConfig(
        port=settings.port_to_open,
        baud=settings.baud,
        echo=settings.echo,
        adapter_latency=settings.timeout,
        retries=settings.retries,
        transport=settings.transport,
        direction=settings.direction,
    )

    options = None
    if robot_file is not None:
        # --timeout and --transport apply to the robot's lines too (imported here: without --robot, the
        # robot's modules stay out of the server's start).
        from ._robot_common import robot_options

        options = robot_options(settings)
        if start_pose is not None:  # (named as typed here: the server's own check says start_pose)
            from ..robot.startup import check_start_pose
            from ._robot_common import load_robot_file

            try:
                check_start_pose(load_robot_file(robot_file), start_pose, named="--start-pose")
            except InvalidArgument as exc:
                raise CliError(ExitCode.USAGE, f"{exc} (nothing was sent)") from None

    def announce(url: str) -> None:
        click.echo(url)
        sys.stdout.flush()

    def warn(text: str) -> None:
        say_labelled("[yellow]warning:[/yellow]", escape(text))

    def note(text: str) -> None:
        clear_after_ctrl_c()  # (said as the server stops: the ^C echoed before it goes)
        say(f"[dim]{escape(text)}[/dim]")

    def no_browser_opened() -> None:
        # (said once: the page is there all the same, at the address on stdout's first line)
        say_labelled(
            "[dim]note:[/dim]",
            "[dim]no browser could be opened here: open the address above in one yourself "
            "(--no-browser: none is tried)[/dim]",
        )

    # A double Ctrl-C's later press may land as the server's event loop closes, cutting short its executor's
    # shutdown, whose thread then reported a closed loop with a traceback: that one report is dropped.
    quiet_executor_shutdown()
    try:
        cut_short = serve(
            config,
            token,
            where,
            open_browser=not no_browser,
            announce=announce,
            warn=warn,
            robot_file=robot_file,
            robot_options=options,
            robot_start_pose=start_pose,
            robot_ask_before_freeing=not yes,
            line_from_robot=line_from_robot,
            note=note,
            no_browser_opened=no_browser_opened,
            loop=loop,
        )
    except InvalidArgument as exc:  # a robot file's error (DescriptionError) included
        raise CliError(ExitCode.USAGE, str(exc)) from None
    except KeyboardInterrupt:
        cut_short = 0
    # Stopped (the server runs until a stop signal): a double Ctrl-C's later press, landing as the command ends, is
    # the same stop, not a death by SIGINT as Python ends.
    same_stop_for_a_moment()
    if cut_short:
        which = "a request" if cut_short == 1 else f"{cut_short} requests"
        raise CliError(
            ExitCode.INTERRUPTED,
            f"interrupted: Ctrl-C again stopped the server at once: {which} it was still answering cut short (done "
            "in part, perhaps: some servos written, a write not read back: read the servos again); the live plots "
            "and motion stopped as at any stop, every servo's torque left as it was (holding ones hold)",
        )
    return 0


COMMANDS = [web]
