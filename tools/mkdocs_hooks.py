"""MkDocs hooks: pages that are generated from the code, so they cannot drift from it.

A page asks for a generated block with an HTML comment on a line of its own:

* ``<!-- generated: exit-codes -->``: the exit-code table, from ``ics35_async.cli._settings.ExitCode``
  (each member's value, name and docstring);
* ``<!-- generated: engine-states -->``: a Mermaid state diagram of the line engine, found by driving
  a real :class:`~ics35_async.engine.LineEngine` through every event from every state it reaches.
"""

from __future__ import annotations

import ast
import copy
import inspect
import itertools
import re
import textwrap
from collections.abc import Callable
from typing import Any

MARK = "<!-- generated: {} -->"


def exit_code_table() -> str:
    """The exit codes as a Markdown table, read from the enum's source (member docstrings)."""
    from ics35_async.cli._settings import ExitCode

    tree = ast.parse(textwrap.dedent(inspect.getsource(ExitCode)))
    body = tree.body[0].body  # type: ignore[attr-defined]
    docs: dict[str, str] = {}
    for node, after in itertools.pairwise(body):
        if (
            isinstance(node, ast.Assign)
            and isinstance(after, ast.Expr)
            and isinstance(after.value, ast.Constant)
            and isinstance(after.value.value, str)
        ):
            docs[node.targets[0].id] = " ".join(after.value.value.split())  # type: ignore[attr-defined]
    missing = [member.name for member in ExitCode if member.name not in docs]
    if missing:
        raise ValueError(f"ExitCode members without a docstring: {', '.join(missing)}")
    rows = ["| code | name | meaning |", "|---|---|---|"]
    rows += [f"| {int(member)} | `{member.name}` | {docs[member.name]} |" for member in ExitCode]
    return "\n".join(rows)


def _engine_events() -> dict[str, Callable[[Any, float], Any]]:
    """Every way a driver can touch the engine, each as a call on an engine copy."""
    from ics35_async import protocol
    from ics35_async.engine.requests import Request

    command = protocol.ReadParam(1, protocol.Param.SPEED)
    answer = command.tx + command.encode_reply(64)

    def submit(engine: Any, now: float) -> Any:
        return engine.submit(Request(command), now)

    def reply(engine: Any, now: float) -> Any:
        return engine.receive(answer, now)

    def garbage(engine: Any, now: float) -> Any:
        return engine.receive(b"\xff\xff\xff\xff\xff", now)

    def deadline(engine: Any, now: float) -> Any:
        return engine.tick(max(now, engine.deadline) + 1.0)

    return {
        "connected": lambda engine, now: engine.connected(now),
        "disconnected": lambda engine, now: engine.disconnected(),
        "request submitted": submit,
        "echo and reply received": reply,
        "bad bytes received": garbage,
        "deadline passed": deadline,
        "port lost (reconnect on)": lambda engine, now: engine.lost("gone", reconnect=True),
        "port lost (reconnect off)": lambda engine, now: engine.lost("gone", reconnect=False),
        "close": lambda engine, now: engine.close(),
        "abort": lambda engine, now: engine.abort(),
    }


PENDING = "_THEN_OFFLINE"
"""Suffix of a state asked offline meanwhile (a reopen while BUSY or QUIET): offline once it ends."""


def _engine_node(engine: Any) -> str:
    """The engine's state, as drawn: a reopen asked while busy is pending in the same state, so it is a node of
    its own (otherwise the diagram would not show where that state then goes)."""
    return engine.state.name + (PENDING if engine.describe(0.0)["going_offline"] else "")


def _node_label(node: str) -> str:
    return node.replace(PENDING, ", then OFFLINE")


def engine_transitions() -> dict[tuple[str, str], list[str]]:
    """(state before, state after) -> the events that lead there, found by trying each event in each state."""
    from ics35_async.engine import LineEngine
    from ics35_async.errors import IcsError

    events = _engine_events()
    start = LineEngine(baudrate=115200)
    seen = {_engine_node(start)}
    todo = [start]
    edges: dict[tuple[str, str], list[str]] = {}
    while todo:
        engine = todo.pop()
        for name, event in events.items():
            trial = copy.deepcopy(engine)
            try:
                event(trial, 0.0)
            except IcsError:  # refused in this state (InvalidArgument, BusClosed, PortLost): no edge
                continue
            before, after = _engine_node(engine), _engine_node(trial)
            if before == after:
                continue
            edges.setdefault((before, after), []).append(name)
            if after not in seen:
                seen.add(after)
                todo.append(trial)
    return edges


def engine_state_diagram() -> str:
    """A Mermaid state diagram of the engine's transitions, and the same as a table (readable without JavaScript)."""
    transitions = sorted(engine_transitions().items())
    pending = sorted({node for edge in dict(transitions) for node in edge if node.endswith(PENDING)})
    lines = ["```mermaid", "stateDiagram-v2"]
    lines += [f'    state "{_node_label(node)}" as {node}' for node in pending]
    lines += ["    [*] --> OFFLINE"]
    lines += [f"    {before} --> {after}: {'; '.join(names)}" for (before, after), names in transitions]
    lines += ["    CLOSED --> [*]", "```", "", "| from | event | to |", "|---|---|---|"]
    lines += [
        f"| {_node_label(before)} | {'; '.join(names)} | {_node_label(after)} |"
        for (before, after), names in transitions
    ]
    return "\n".join(lines)


GENERATORS: dict[str, Callable[[], str]] = {
    "exit-codes": exit_code_table,
    "engine-states": engine_state_diagram,
}


# Docstrings use Sphinx roles (:class:`Bus`), which Markdown renders as ':class:' before the code.
_ROLE = re.compile(r":(?:class|meth|func|mod|attr|exc|data|obj):<code>~?([^<]*)</code>")


def _role_text(match: re.Match[str]) -> str:
    name = match.group(1)
    if match.group(0).split("<code>", 1)[1].startswith("~"):
        name = name.rpartition(".")[2]  # Sphinx's ~: show the last part only
    return f"<code>{name}</code>"


def on_page_content(html: str, **kwargs: Any) -> str:
    html = _ROLE.sub(_role_text, html)
    # click 8.2 marks an unset flag default with a sentinel, which mkdocs-click prints as is.
    return html.replace("<code>Sentinel.UNSET</code>", "<code>False</code>")


def on_page_markdown(markdown: str, **kwargs: Any) -> str:
    for name, generate in GENERATORS.items():
        mark = MARK.format(name)
        if mark in markdown:
            markdown = markdown.replace(mark, generate())
    return markdown
