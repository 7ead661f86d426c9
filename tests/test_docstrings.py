"""Every public class, function, method and property of the public API has a docstring that names
its parameters and the library errors it raises itself.

"Public API" is what users import: the names in ``__all__`` of ``ics35_async`` and of its
``blocking``, ``policies``, ``robot`` and ``sim`` packages. A member is public unless its name
starts with an underscore. The docs site's reference is generated from these docstrings, so a
missing one is a hole in the docs.

What is checked, and why it is sound:

- a docstring on every public class, function, method and property;
- every parameter of a public function or method (``__init__``: in the class's docstring) is
  named in its docstring; a dataclass's generated ``__init__`` is left out (its fields are the
  class's documented attributes);
- a ``raise SomeError(...)`` of one of the library's errors written in a public callable's own
  body (not in a nested function) is named in its docstring, that error or a base of it. Errors
  raised by the helpers it calls are not followed: that would need the whole call graph, so the
  docstrings say those by hand.
"""

from __future__ import annotations

import ast
import dataclasses
import enum
import importlib
import inspect
import textwrap
from collections.abc import Callable, Iterator

import pytest

from ics35_async import errors

PACKAGES = ["ics35_async", "ics35_async.blocking", "ics35_async.policies", "ics35_async.robot", "ics35_async.sim"]
OUR_ERRORS = {
    name: cls for name, cls in vars(errors).items() if inspect.isclass(cls) and issubclass(cls, errors.IcsError)
}


def _public_objects() -> dict[str, object]:
    found: dict[str, object] = {}
    for package in PACKAGES:
        module = importlib.import_module(package)
        for name in module.__all__:
            obj = getattr(module, name)
            if not name.startswith("_") and (inspect.isclass(obj) or inspect.isfunction(obj)):
                found.setdefault(f"{obj.__module__}.{obj.__qualname__}", obj)
    return found


def _members(obj: type) -> Iterator[tuple[str, object]]:
    for name, member in vars(obj).items():
        if name.startswith("_") and name != "__init__":
            continue
        if isinstance(member, (staticmethod, classmethod)):
            member = member.__func__
        yield name, member


def _undocumented(qualname: str, obj: object) -> list[str]:
    missing = [] if inspect.getdoc(obj) else [qualname]
    if not inspect.isclass(obj) or issubclass(obj, (BaseException, enum.Enum)):
        return missing  # an error's or an enum's members are documented by the class
    for name, member in _members(obj):
        if name == "__init__":
            continue
        if (inspect.isfunction(member) or isinstance(member, property)) and not member.__doc__:
            missing.append(f"{qualname}.{name}")
    return missing


def _callables(qualname: str, obj: object) -> Iterator[tuple[str, Callable[..., object], str]]:
    """(name, function, the docstring that documents it) for ``obj`` and its public methods."""
    if inspect.isfunction(obj):
        yield qualname, obj, inspect.getdoc(obj) or ""
        return
    assert inspect.isclass(obj)
    if issubclass(obj, enum.Enum):
        return
    for name, member in _members(obj):
        if not inspect.isfunction(member) or getattr(member, "__wrapped__", None) is not None:
            continue  # a wrapper made from a documented function (blocking's forwarders) says what that says
        if name == "__init__":
            # A dataclass: its fields are its attributes; an error: its message and fields; a protocol: none.
            if dataclasses.is_dataclass(obj) or issubclass(obj, BaseException) or getattr(obj, "_is_protocol", False):
                continue
            yield f"{qualname}.__init__", member, inspect.getdoc(obj) or ""
        else:
            yield f"{qualname}.{name}", member, inspect.getdoc(member) or ""


def _parameters_not_named(function: Callable[..., object], doc: str) -> list[str]:
    names = [p.name for p in inspect.signature(function).parameters.values() if p.name not in ("self", "cls")]
    return [name for name in names if name not in doc]


def _errors_raised_here(function: Callable[..., object]) -> set[str]:
    """Our errors that ``function``'s own body raises by name (nested functions left out)."""
    try:
        tree = ast.parse(textwrap.dedent(inspect.getsource(function)))
    except (OSError, TypeError, SyntaxError):
        return set()
    found: set[str] = set()

    def visit(node: ast.AST) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda, ast.ClassDef)):
                continue
            if isinstance(child, ast.Raise) and child.exc is not None:
                raised = child.exc.func if isinstance(child.exc, ast.Call) else child.exc
                name = raised.id if isinstance(raised, ast.Name) else getattr(raised, "attr", "")
                if name in OUR_ERRORS:
                    found.add(name)
            visit(child)

    visit(tree.body[0])
    return found


def _errors_not_named(function: Callable[..., object], doc: str) -> list[str]:
    return sorted(
        name
        for name in _errors_raised_here(function)
        if not any(base in doc for base, cls in OUR_ERRORS.items() if issubclass(OUR_ERRORS[name], cls))
    )


PUBLIC = _public_objects()


def test_the_public_api_is_found() -> None:
    assert "ics35_async.bus.open_bus" in PUBLIC
    assert "ics35_async.bus.Bus" in PUBLIC
    assert "ics35_async.sim.virtual_line.VirtualLine" in PUBLIC
    assert len(PUBLIC) > 40


@pytest.mark.parametrize("qualname", sorted(PUBLIC))
def test_public_member_has_a_docstring(qualname: str) -> None:
    assert _undocumented(qualname, PUBLIC[qualname]) == []


@pytest.mark.parametrize("qualname", sorted(PUBLIC))
def test_docstrings_name_the_parameters_and_the_errors_raised(qualname: str) -> None:
    gaps = []
    for name, function, doc in _callables(qualname, PUBLIC[qualname]):
        gaps += [f"{name}: parameter {p}" for p in _parameters_not_named(function, doc)]
        gaps += [f"{name}: raises {e}" for e in _errors_not_named(function, doc)]
    assert gaps == []


def test_the_checks_can_fail() -> None:
    class Undocumented:
        def method(self) -> None:
            pass

    def quiet(port: str, *, retries: int = 0) -> None:
        """Open ``port``."""
        if retries < 0:
            raise errors.UnsafeOperation("no")

    def says(port: str) -> None:
        """Open ``port``.

        Raises:
            InvalidArgument: a bad port.
        """

        def helper() -> None:
            raise errors.BusClosed("not this function's own raise")

        raise errors.UnsafeOperation("a subclass of InvalidArgument, so named by the docstring")

    assert _undocumented("Undocumented", Undocumented) == ["Undocumented", "Undocumented.method"]
    assert _parameters_not_named(quiet, inspect.getdoc(quiet) or "") == ["retries"]
    assert _errors_not_named(quiet, inspect.getdoc(quiet) or "") == ["UnsafeOperation"]
    assert _errors_not_named(says, inspect.getdoc(says) or "") == []
