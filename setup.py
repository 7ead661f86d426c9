"""The compiled burst executor (ics35_async.drivers._burst); everything else is in pyproject.toml.

``optional=True``: where it cannot be built (no C compiler, Windows) the package installs
without it and every port runs on the ordinary path.
"""

import sys

from setuptools import Extension, setup

ext_modules = []
if sys.platform != "win32":  # POSIX descriptors, poll and threads only
    ext_modules.append(
        Extension(
            "ics35_async.drivers._burst", ["ics35_async/drivers/_burst.c"], optional=True, extra_compile_args=["-O2"]
        )
    )

setup(ext_modules=ext_modules)
