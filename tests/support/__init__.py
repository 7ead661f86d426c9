"""Oracles and helpers shared by the test suite and the reliability soaks (benchmarks/soak).

* :mod:`.oracle` -- what the bus must conclude from the bytes it received (:class:`~.oracle.WirePredictor`);
* :mod:`.matcher` -- every outcome lined up with the simulator's log entry of its transaction;
* :mod:`.fuzzing` -- fuzzed transactions, a scripted WireDevice double and a rig of buses on them;
* :mod:`.leaks` -- counts of tasks, file descriptors and threads, for leak checks.

The tests import this package as ``tests.support`` (pytest puts the project root on ``sys.path``
because ``tests`` is a package); ``python -m benchmarks.soak``, run from the project root, does the same.
"""
