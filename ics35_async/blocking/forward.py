"""Blocking methods made from the async API's own methods, signatures and all.

``set_position = blocking(Servo.set_position)`` in a :class:`Wrapper` subclass
gives a method that takes what ``Servo.set_position`` takes (mypy checks
calls against the async signature) and returns what it returns, run on the
wrapper's loop thread.  ``on_loop`` does the same for plain methods of
objects that live on the loop (a stream's ``set_targets``), which must not
be touched from another thread while the loop runs them.  ``ReadThrough``
makes a read-only attribute that reads the async object's own.
"""

from __future__ import annotations

import inspect
from collections.abc import Awaitable, Callable
from typing import Any, Concatenate, Generic, Never, ParamSpec, TypeVar, overload

from .loop_thread import LoopThread

A = TypeVar("A")  # the async object a wrapper stands for
P = ParamSpec("P")
T = TypeVar("T")


class Wrapper(Generic[A]):
    """A blocking stand-in for an async object: ``_async`` runs on ``_loop``."""

    __slots__ = ("_async", "_loop")

    def __init__(self, target: A, loop: LoopThread) -> None:
        self._async = target
        self._loop = loop


class _Forward(Generic[A, P, T]):
    """The descriptor ``blocking`` and ``on_loop`` make: ``awaits`` says whether ``method`` is a coroutine
    function (awaited on the loop) or a plain one (called on the loop thread)."""

    __signature__: inspect.Signature

    def __init__(self, method: Callable[Concatenate[A, P], Any], *, awaits: bool, reads: bool = False) -> None:
        self._method = method
        self._awaits = awaits
        self._reads = reads
        self.__doc__ = method.__doc__
        self.__name__ = self.__qualname__ = getattr(method, "__name__", "method")
        # What help() and inspect.signature() show: the async method's signature, ``self`` and all, for the
        # class's (help(BlockingServo) lists it, as it would a method); without ``self`` for an object's.
        self.__signature__ = inspect.signature(method)
        self._signature = self.__signature__.replace(parameters=list(self.__signature__.parameters.values())[1:])

    def __set_name__(self, owner: type, name: str) -> None:
        self.__name__, self.__qualname__, self.__module__ = name, f"{owner.__qualname__}.{name}", owner.__module__

    @overload
    def __get__(self, obj: None, owner: type | None = None) -> _Forward[A, P, T]: ...

    @overload
    def __get__(self, obj: Wrapper[A], owner: type | None = None) -> Callable[P, T]: ...

    def __get__(self, obj: Wrapper[A] | None, owner: type | None = None) -> _Forward[A, P, T] | Callable[P, T]:
        if obj is None:
            return self
        method, target, loop = self._method, obj._async, obj._loop
        run: Callable[..., T] = loop.call if self._awaits else loop.read if self._reads else loop.call_sync

        def call(*args: P.args, **kwargs: P.kwargs) -> T:
            return run(method, target, *args, **kwargs)

        call.__name__, call.__qualname__, call.__module__ = self.__name__, self.__qualname__, self.__module__
        call.__doc__ = self.__doc__
        call.__signature__ = self._signature  # type: ignore[attr-defined]
        return call

    def __call__(self, obj: Wrapper[A], /, *args: P.args, **kwargs: P.kwargs) -> T:
        """Called through the class (``BlockingServo.set_position(servo, 9000)``), as a method can be; being
        callable is also what lets help() and inspect.signature() show the class's method with its arguments."""
        return self.__get__(obj)(*args, **kwargs)


def blocking(method: Callable[Concatenate[A, P], Awaitable[T]]) -> _Forward[A, P, T]:
    """A blocking method that awaits the async ``method`` on the wrapper's loop thread."""
    return _Forward(method, awaits=True)


def on_loop(method: Callable[Concatenate[A, P], T]) -> _Forward[A, P, T]:
    """A blocking method that runs the plain ``method`` on the wrapper's loop thread."""
    return _Forward(method, awaits=False)


def read_on_loop(method: Callable[Concatenate[A, P], T]) -> _Forward[A, P, T]:
    """Like :func:`on_loop`, for a method that only reads state: once the loop thread has ended, it
    reads here (see ``LoopThread.read``)."""
    return _Forward(method, awaits=False, reads=True)


class ReadThrough(Generic[T]):
    """A read-only attribute of a wrapper that reads the async object's attribute of the same name:
    ``id = ReadThrough[int]("The servo's ID (0..31).")``.  Read from the caller's thread with no hop to the
    loop: only for attributes that hold an immutable value, read in one step (an ID, a state, a frame)."""

    def __init__(self, doc: str) -> None:
        self.__doc__ = doc
        self._name = ""

    def __set_name__(self, owner: type, name: str) -> None:
        self._name = name

    @overload
    def __get__(self, obj: None, owner: type | None = None) -> ReadThrough[T]: ...

    @overload
    def __get__(self, obj: Wrapper[Any], owner: type | None = None) -> T: ...

    def __get__(self, obj: Wrapper[Any] | None, owner: type | None = None) -> ReadThrough[T] | T:
        if obj is None:
            return self
        value: T = getattr(obj._async, self._name)
        return value

    def __set__(self, obj: Wrapper[Any], value: Never) -> None:  # Never: type checkers refuse any assignment
        raise AttributeError(f"{self._name} is read-only")
