"""Every public class, function, method and property of the public API has a docstring.

"Public API" is what users import: the names in ``__all__`` of ``ics35_async`` and of its
``blocking``, ``policies`` and ``robot`` packages. A member is public unless its name starts
with an underscore. The docs site's reference is generated from these docstrings, so a
missing one is a hole in the docs.
"""

from __future__ import annotations

import enum
import importlib
import inspect

import pytest

PACKAGES = ["ics35_async", "ics35_async.blocking", "ics35_async.policies", "ics35_async.robot"]


def _public_objects() -> dict[str, object]:
    found: dict[str, object] = {}
    for package in PACKAGES:
        module = importlib.import_module(package)
        for name in module.__all__:
            obj = getattr(module, name)
            if not name.startswith("_") and (inspect.isclass(obj) or inspect.isfunction(obj)):
                found.setdefault(f"{obj.__module__}.{obj.__qualname__}", obj)
    return found


def _undocumented(qualname: str, obj: object) -> list[str]:
    missing = [] if inspect.getdoc(obj) else [qualname]
    if not inspect.isclass(obj) or issubclass(obj, (BaseException, enum.Enum)):
        return missing  # an error's or an enum's members are documented by the class
    for name, member in vars(obj).items():
        if name.startswith("_"):
            continue
        if isinstance(member, (staticmethod, classmethod)):
            member = member.__func__
        if (inspect.isfunction(member) or isinstance(member, property)) and not member.__doc__:
            missing.append(f"{qualname}.{name}")
    return missing


PUBLIC = _public_objects()


def test_the_public_api_is_found() -> None:
    assert "ics35_async.bus.open_bus" in PUBLIC
    assert "ics35_async.bus.Bus" in PUBLIC
    assert len(PUBLIC) > 40


@pytest.mark.parametrize("qualname", sorted(PUBLIC))
def test_public_member_has_a_docstring(qualname: str) -> None:
    assert _undocumented(qualname, PUBLIC[qualname]) == []


def test_the_check_can_fail() -> None:
    class Undocumented:
        def method(self) -> None:
            pass

    assert _undocumented("Undocumented", Undocumented) == ["Undocumented", "Undocumented.method"]
