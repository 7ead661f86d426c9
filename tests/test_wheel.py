"""The package as users get it: build the wheel and sdist, install the wheel into a clean
virtualenv, and run the CLI and an API example from there against the simulator.

This needs the ``build`` package and setuptools>=77 (both in the ``dev`` extra) and pip's
access to the package index (or its cache) for the wheel's dependencies.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import tarfile
import venv
import zipfile
from pathlib import Path

import pytest

# (Building the wheel compiles the engine with mypyc: about 35 s of CPU, minutes beside the stress run's burners.)
pytestmark = [pytest.mark.slow, pytest.mark.timeout(600)]

ROOT = Path(__file__).resolve().parent.parent
EXAMPLE = re.findall(r"^```python\n(.*?)^```", (ROOT / "README.md").read_text(), flags=re.S | re.M)[0]


def _run(*args: str | Path, cwd: Path, timeout: float = 300) -> subprocess.CompletedProcess[str]:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    return subprocess.run([str(a) for a in args], cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)


@pytest.fixture(scope="module")
def dist(tmp_path_factory: pytest.TempPathFactory) -> Path:
    pytest.importorskip("build", reason="python -m build needs the build package (pip install -e '.[dev]')")
    out = tmp_path_factory.mktemp("dist")
    done = _run(sys.executable, "-m", "build", "--no-isolation", "--outdir", out, ROOT, cwd=ROOT)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    return out


def test_wheel_and_sdist_carry_the_license_and_the_sdist_no_unrunnable_tests(dist: Path) -> None:
    (wheel,) = dist.glob("*.whl")
    (sdist,) = dist.glob("*.tar.gz")
    with zipfile.ZipFile(wheel) as archive:
        names = archive.namelist()
    assert any(n.endswith(".dist-info/licenses/LICENSE") for n in names), names
    assert "ics35_async/py.typed" in names
    # The compiled helper's types ship with it; on Linux (where the tests build it) the helper itself too.
    assert "ics35_async/drivers/_burst.pyi" in names
    if sys.platform.startswith("linux"):
        assert any(n.startswith("ics35_async/drivers/_burst.") and n.endswith(".so") for n in names), names
        # ... and the engine's rules compiled by mypyc, beside their sources (setup.py)
        for module in ("ics35_async/engine/machine.", "ics35_async/_compiled__mypyc."):
            assert any(n.startswith(module) and n.endswith(".so") for n in names), (module, names)
        assert "ics35_async/engine/machine.py" in names
    with zipfile.ZipFile(wheel) as archive:
        (metadata_name,) = [n for n in names if n.endswith(".dist-info/METADATA")]
        metadata = archive.read(metadata_name).decode()
    for label in ("Homepage", "Documentation", "Changelog", "Issues"):
        assert f"Project-URL: {label}, https://" in metadata, label
    for classifier in ("Typing :: Typed", "Framework :: AsyncIO", "Framework :: Trio", "Framework :: AnyIO"):
        assert f"Classifier: {classifier}" in metadata, classifier
    with tarfile.open(sdist) as archive:
        members = [m.split("/", 1)[1] for m in archive.getnames() if "/" in m]
    assert "LICENSE" in members and "CHANGELOG.md" in members
    assert "ics35_async/drivers/_burst.c" in members  # so an sdist install builds the helper
    # The engine ships as source (an sdist install compiles it); nothing built or generated goes in.
    assert "ics35_async/engine/machine.py" in members
    assert [m for m in members if m.endswith((".so", ".c"))] == ["ics35_async/drivers/_burst.c"]
    assert not [m for m in members if m.startswith("tests/")], "the sdist ships tests it cannot run"


def test_wheel_installs_into_a_clean_virtualenv_and_runs(dist: Path, tmp_path: Path) -> None:
    (wheel,) = dist.glob("*.whl")
    env_dir = tmp_path / "venv"
    # Without a pip of its own (installing one costs more than the rest of the test): this pip installs into
    # it (--python), without compiling every dependency's modules up front (imports compile what they use).
    venv.create(env_dir, with_pip=False)
    bin_dir = env_dir / ("Scripts" if os.name == "nt" else "bin")
    done = _run(
        sys.executable,
        "-m",
        "pip",
        "--python",
        bin_dir / "python",
        "install",
        "--quiet",
        "--no-compile",
        wheel,
        cwd=tmp_path,
        timeout=600,
    )
    assert done.returncode == 0, done.stderr[-3000:]

    where = _run(bin_dir / "python", "-c", "import ics35_async; print(ics35_async.__file__)", cwd=tmp_path)
    assert where.returncode == 0, where.stderr
    assert Path(where.stdout.strip()).is_relative_to(env_dir), "imported the work tree, not the wheel"

    scan = _run(bin_dir / "ics35", "--port", "sim://?ids=1-3", "scan", "--bauds", "115200", cwd=tmp_path)
    assert scan.returncode == 0, scan.stderr
    assert "3 servo(s) found" in scan.stdout + scan.stderr

    version = _run(bin_dir / "ics35", "--version", cwd=tmp_path)
    assert version.returncode == 0 and "0." in version.stdout

    # The wheel's build compiles the engine's rules (mypy is in the dev extra: setup.py), and says so.
    verbose = _run(bin_dir / "ics35", "--version", "-v", cwd=tmp_path)
    assert "compiled engine: on (" in verbose.stdout, verbose.stdout

    script = tmp_path / "example.py"
    script.write_text(EXAMPLE)
    example = _run(bin_dir / "python", script, cwd=tmp_path)
    assert example.returncode == 0, example.stderr
    assert "servos: [1, 2, 3]" in example.stdout


def test_the_development_install_is_a_path_entry_type_checkers_follow() -> None:
    # An editable install of a flat layout was an import hook (a finder type checkers cannot see) unless asked for
    # setuptools' transitional compat mode, which warned at every `make demo`: package-dir makes it a path entry.
    import json
    from importlib import metadata

    # (the installed one: the build's own ics35_async.egg-info in the checkout, first on a test's path, has no
    # record of how it was installed)
    (installed,) = [d for d in metadata.distributions(name="ics35_async") if d.read_text("direct_url.json") is not None]
    direct = json.loads(installed.read_text("direct_url.json") or "{}")
    assert direct.get("dir_info", {}).get("editable"), direct  # (make .venv/.installed)
    clone = Path(direct["url"].removeprefix("file://"))
    files = [str(f) for f in installed.files or ()]
    assert not [f for f in files if "finder" in f], files
    (pth,) = [f for f in files if f.endswith(".pth")]
    entries = Path(str(installed.locate_file(pth))).read_text().split()
    assert [Path(e).resolve() for e in entries] == [clone.resolve()], entries


def test_an_editable_install_is_told_as_one_with_a_build_record_first_on_the_path(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The build's ics35_async.egg-info in a checkout, first on the path when the CLI runs from it (`python -m
    # ics35_async.cli` there, a test), was taken for the installation: "a package", and `ics35 web` without its extra
    # said to fetch a second copy from the package index instead of `pip install -e 'CLONE[web]'`.
    from ics35_async.extras import installed_from

    told = installed_from()
    assert told[0] == "editable", told  # (make .venv/.installed)
    record = tmp_path / "ics35_async.egg-info"
    record.mkdir()
    (record / "PKG-INFO").write_text("Metadata-Version: 2.1\nName: ics35_async\nVersion: 0.1.0\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    assert installed_from() == told
