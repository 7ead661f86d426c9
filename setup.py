"""The compiled parts: the burst executor (C) and the engine's rules compiled by mypyc; everything else is in
pyproject.toml.

Both are optional: where they cannot be built (no C compiler, Windows, mypy missing) the package installs
without them and runs the same code as plain Python.  The engine's rules are written once, in Python:
mypyc compiles those modules as they are (see docs/development/benchmarks.md, "The compiled engine").

``ICS35_COMPILE=0`` builds without mypyc.  A build in place (an editable install, ``build_ext --inplace``)
skips it unless ``ICS35_COMPILE=1``: compiled modules beside their sources would shadow every later edit
until rebuilt.
"""

import gc
import os
import sys
import warnings

from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext

# The engine's rules: what every transaction runs through.  Not engine/requests.py (the drivers subclass its
# Request: an interpreted class cannot inherit a compiled one), nor the stream and the public API: compiled
# code refuses an argument of the wrong type with its own TypeError, before the library's clear errors (and
# NumPy numbers, which the API takes as the Python numbers they equal).
COMPILED = [
    "ics35_async/engine/counters.py",
    "ics35_async/engine/guard.py",
    "ics35_async/engine/link.py",
    "ics35_async/engine/machine.py",
    "ics35_async/engine/outcome.py",
    "ics35_async/engine/probe.py",
    "ics35_async/engine/source.py",
]


# mypyc needs the modules' types, not the project's strict checks (pyproject's [tool.mypy], for development), and
# an isolated build has none of the package's dependencies (anyio, pyserial): the modules they type are read for
# their types only (silent), and a missing one is Any.  tests/test_compiled_engine.py runs mypy with these options
# without site-packages, as an isolated build does.
MYPYC_OPTIONS = ["--config-file=", "--follow-imports=silent", "--ignore-missing-imports"]


def compile_setting() -> str:
    return os.environ.get("ICS35_COMPILE", "").strip().lower()


def mypyc_extensions() -> list[Extension]:
    """The compiled modules' extensions, or none (with a warning) where mypy is missing or refuses them."""
    try:
        from mypyc.build import mypycify
    except ImportError:
        warnings.warn("mypy is not installed: the engine is not compiled (it runs as plain Python)", stacklevel=1)
        return []
    try:
        extensions: list[Extension] = mypycify(
            [*MYPYC_OPTIONS, *COMPILED], opt_level="3", group_name="ics35_async._compiled"
        )
    except (Exception, SystemExit) as exc:  # (mypy exits on a type error, having printed it)
        warnings.warn(f"the engine is not compiled (mypy refused it: {exc!r}): it runs as plain Python", stacklevel=1)
        return []
    # mypy's analysis stays in memory (some two million objects), and the garbage collector would walk it again at
    # each full collection of the rest of the build and at exit: about 7 s of CPU, as much as the type checking.
    # Frozen, the collector leaves it alone (the memory goes with the build's process).
    gc.freeze()
    return extensions


class BuildExt(build_ext):
    """Adds the mypyc-compiled modules when wanted, and drops them all if any fails to build."""

    def run(self) -> None:
        # (Here, not in finalize_options: egg_info finalizes this command too, and mypyc checks types first.)
        self._mypyc: set[str] = set()
        self._mypyc_failed = False
        self._mypyc_built: list[str] = []
        setting = compile_setting()
        wanted = setting in ("1", "yes", "on", "true") or (
            not self.inplace and setting not in ("0", "no", "off", "false")
        )
        compiled = mypyc_extensions() if wanted else []
        for ext in compiled:  # what finalize_options notes of every extension (no shared libraries here)
            ext._full_name = self.get_ext_fullname(ext.name)
            self.ext_map[ext._full_name] = ext
            ext._links_to_dynamic = ext._needs_stub = False
            ext._file_name = self.get_ext_filename(ext._full_name)
            ext.optional = True  # (a build in place then copies only what was built)
        self._mypyc = {ext.name for ext in compiled}
        self.extensions = [*self.extensions, *compiled]
        super().run()

    def build_extension(self, ext: Extension) -> None:
        if ext.name not in self._mypyc:
            super().build_extension(ext)
            return
        if self._mypyc_failed:
            return
        try:
            super().build_extension(ext)
        except Exception as exc:  # (a compiler error of any kind: the plain modules serve)
            # A module's compiled stub without the group's shared library would not import: none of them stay.
            self._mypyc_failed = True
            for path in self._mypyc_built:
                if os.path.exists(path):
                    os.remove(path)
            warnings.warn(f"the engine is not compiled ({exc}): it runs as plain Python", stacklevel=1)
        else:
            self._mypyc_built.append(self.get_ext_fullpath(ext.name))

    def get_outputs(self) -> list[str]:
        failed = getattr(self, "_mypyc_failed", False)
        return [path for path in super().get_outputs() if not failed or os.path.exists(path)]


if __name__ == "__main__":  # (as setuptools runs it; the tests read the constants above)
    ext_modules = []
    cmdclass = {}
    if sys.platform != "win32":  # POSIX descriptors, poll and threads only
        ext_modules.append(
            Extension(
                "ics35_async.drivers._burst",
                ["ics35_async/drivers/_burst.c"],
                optional=True,
                extra_compile_args=["-O2"],
            )
        )
        cmdclass["build_ext"] = BuildExt
    setup(ext_modules=ext_modules, cmdclass=cmdclass)
