"""Shared fixtures: CLI runner and small recordings generated once per session."""

from __future__ import annotations

import gc
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest
from click.testing import CliRunner

# One BLAS thread per process, set before anything loads numpy here, and inherited by the xdist
# workers and every subprocess the tests start: the suite is already parallel (three workers, a
# hundred subprocesses, real-time devices), and OpenBLAS's own threads, spinning while they wait for
# work, took a third of the CPU on this 2-core machine (the plant, LMS, runout and FRF tests: 116
# CPU-s with OpenBLAS's default threads, 79 with one; wall 59 s and 43 s). Our matrices are small
# (4 x 4 per frequency, batched): one thread computes them as fast.
for _blas in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_blas, "1")

from ambdaq.cli.main import cli  # noqa: E402  (after the threads are set)

import scheduling  # noqa: E402  (tests/scheduling.py: the third worker)


WARM = """import sys
import numpy as np
from ambdaq.analysis.runout import lms_offline
from ambdaq.sim.source import SimSource
for p in sys.argv[1:]:
    if p == "runout":  # the offline LMS's kernel (runout identify --method lms)
        x, th = np.zeros(200), np.linspace(0.0, 20.0, 200)
        lms_offline(x, th, harmonics=(1, 2))
    else:
        s = SimSource(p)
        s.start(10)
        s.read()
"""


def _warm_rigs() -> list[subprocess.Popen]:
    """Start compiling the rigs' numba kernels (and the offline LMS's) once, two at a time, while
    the workers start and collect; returns the processes to wait for.  In a fresh clone every process that needs
    a kernel before its cache file exists compiles it again (5 s for the spindle's): the two workers
    and the servers and recorders the first tests start.  The two processes are balanced by what
    each kernel took to compile here (spindle 5.8 s, cone 3.3, base-motion 3.0, flexible 2.7,
    lorentz 2.2, runout 1.3; each process 1.3 s to start): 10.6 and 10.3 s, where the first split
    took 8.4 and 12.5."""
    import ambdaq

    if any((Path(ambdaq.__file__).parent / "sim" / "rigs" / "__pycache__").glob("spindle._simulate-*.nbi")):
        return []
    return [subprocess.Popen([sys.executable, "-c", WARM, *kernels])
            for kernels in (("spindle", "runout", "lorentz"), ("cone", "base-motion", "flexible"))]


def pytest_configure(config):
    """Caches (the parsed A2L files) and the state ambdaq keeps (its push and parameter logs) go to
    folders of this run, not the user's ~/.cache and ~/.local/state; the rigs' kernels are compiled
    once by the controlling process (not on an xdist worker).

    Every process of the run writes the bytecode of what it imports, whatever the environment says
    (PYTHONDONTWRITEBYTECODE, set on this machine): the workers and the suite's hundred
    subprocesses would otherwise each compile every module they import, every time (74 s longer on
    a fresh clone here). The first to import a module writes it (atomically: importlib writes a
    temporary file and renames it), the rest read it; compiling the whole environment before the
    workers started instead took 30 s of a fresh clone, most of it on packages no test imports."""
    os.environ["XDG_CACHE_HOME"] = _run_dir("ambdaq-cache-")
    if hasattr(config, "workerinput"):
        gc.set_threshold(*WORKER_GC_THRESHOLDS)
    os.environ["AMBDAQ_STATE_DIR"] = _run_dir("ambdaq-state-")
    os.environ.pop("PYTHONDONTWRITEBYTECODE", None)
    sys.dont_write_bytecode = False
    if not hasattr(config, "workerinput"):
        os.environ[scheduling.OFFLINE_LIST] = str(Path(_run_dir("ambdaq-sched-")) / "offline.txt")
        _WARMING.extend(_warm_rigs())
        if _WARMING:  # a fresh clone: what the workers' collection imports, compiled once before they start
            _import_tests_once()


WORKER_GC_THRESHOLDS = (700, 10, 100)
"""The workers' garbage collector: a full pass after 100 of the middle generation's, not Python's 10.
A worker holds 450,000 to 720,000 objects by the end of a run (numpy, scipy, pandas, matplotlib,
numba ... and what the tests cached) and Python's thresholds walked all of them 13 to 19 times a
run: 10 to 27 s of each worker's time, measured by gc.callbacks. The young generations are as
Python sets them; cyclic garbage lives longer (a test that needs it gone calls gc.collect)."""


_RUN_DIRS: list[str] = []
"""The folders this process made for the run (:func:`_run_dir`), removed when it ends."""


def _run_dir(prefix: str) -> str:
    """A fresh folder for this run, removed at its end (pytest_unconfigure): each process of every
    run made three and left them (458 of each kind had gathered in /tmp here)."""
    _RUN_DIRS.append(tempfile.mkdtemp(prefix=prefix))
    return _RUN_DIRS[-1]


def pytest_unconfigure(config):
    """The run's folders go (:func:`_run_dir`), each process its own."""
    while _RUN_DIRS:
        shutil.rmtree(_RUN_DIRS.pop(), ignore_errors=True)


IMPORT_TESTS = """import importlib, pathlib, sys
root = pathlib.Path(sys.argv[1])
for folder in (root, root / "validation"):
    sys.path.insert(0, str(folder))
for path in sorted(root.glob("test_*.py")) + sorted((root / "validation").glob("test_*.py")):
    try:
        importlib.import_module(path.stem)
    except Exception:
        pass  # the workers' collection reports it
"""


def _import_tests_once() -> None:
    """Import every test module once, in one process, beside the kernels' compilers and before the
    workers start: in a fresh environment (uv installs no bytecode) each worker collecting at the
    same time compiled the same modules of numpy, scipy, pandas ... again (18 s each); one process
    writes them, and the workers read them."""
    subprocess.run([sys.executable, "-c", IMPORT_TESTS, str(Path(__file__).parent)], stdout=subprocess.DEVNULL,
                   stderr=subprocess.DEVNULL, timeout=300)


def pytest_xdist_make_scheduler(config, log):
    """With three workers or more, the last one runs on idle CPU only and takes the ``offline``
    tests (tests/scheduling.py); with two, pytest-xdist's own ``loadgroup``."""
    if scheduling.background_worker(config.option.numprocesses):
        return scheduling.BackgroundScheduling(config, log)
    return None


@pytest.hookimpl(trylast=True)
def pytest_collection_modifyitems(config, items):
    """Each worker names the ``offline`` tests it collected, for the scheduler."""
    if hasattr(config, "workerinput"):
        scheduling.write_offline(items)


_WARMING: list[subprocess.Popen] = []
"""The controlling process's kernel compilers (:func:`_warm_rigs`), waited for before any test runs."""


@pytest.hookimpl(tryfirst=True)
def pytest_runtestloop(session):
    """The kernels compiled before the first test runs: the controlling process waits here, after
    pytest-xdist started its workers and while they collect the tests (6-8 s on a fresh clone that
    the kernels' 10.6 s no longer add to), and before it hands them a test."""
    while _WARMING:
        _WARMING.pop().wait()


def pytest_collection_finish(session):
    """The background worker (tests/scheduling.py) goes to idle CPU once it has collected: the run
    starts when every worker has, and collecting at the others' priority it is not the last.

    On an xdist worker with ``--dist loadgroup``, a grouped test's id ends with ``@GROUP``: that is
    how pytest-xdist keeps a group (the fleet tests' one fixture) on one worker.  pytest 9.2 computes
    ids in a way xdist 3.8 cannot amend, and groups were then silently ignored: refuse to run
    instead (pyproject.toml pins pytest below 9.2)."""
    worker = getattr(session.config, "workerinput", None)
    if worker is not None and worker["workerid"] == scheduling.background_worker(worker["workercount"]):
        scheduling.run_in_background()
    if not getattr(session.config.option, "loadgroup", False):
        return
    lost = [i.nodeid for i in session.items if i.get_closest_marker("xdist_group") and "@" not in i.nodeid]
    if lost:
        raise pytest.UsageError(f"xdist_group is not applied (pytest {pytest.__version__}): {lost[0]} would not run "
                                "in its group; install the pinned test extra (pip install -e '.[test]')")


def npm_installed(tmp_path_factory, folder: Path, files: tuple[str, ...]) -> Path:
    """A copy of ``folder``'s ``files`` with its package.json's pinned packages installed from the
    npm registry (an independent peer: a Foxglove client, Foxglove's parser), in a fresh folder."""
    import shutil

    npm = shutil.which("npm")
    assert npm and shutil.which("node"), f"{folder.name} needs Node.js and npm"
    d = tmp_path_factory.mktemp(folder.name)
    for name in ("package.json", *files):
        shutil.copy(folder / name, d / name)
    r = subprocess.run([npm, "install", "--no-audit", "--no-fund", "--loglevel=error"], cwd=d, capture_output=True,
                       text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    return d


@pytest.fixture
def run_cli():
    """Invoke ``ambdaq ARGS...`` through click's runner; returns the result (exit_code, output)."""
    runner = CliRunner()

    def invoke(*args: str):
        return runner.invoke(cli, [str(a) for a in args], catch_exceptions=False)

    return invoke


@pytest.fixture(scope="session")
def build_once(tmp_path_factory):
    """``build_once(name, build)``: a directory that ``build(dir)`` fills once per run, whichever
    xdist worker asks first; the others wait for it and reuse it.  For artefacts that compute-only
    tests and a real-time one both need: the real-time worker then rarely builds them itself."""
    import fcntl

    base = tmp_path_factory.getbasetemp()
    shared = base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base  # every worker's parent

    def get(name: str, build) -> Path:
        out = shared / f"shared-{name}"
        with open(shared / f"shared-{name}.lock", "w") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            if not (out / ".built").exists():
                out.mkdir(exist_ok=True)
                build(out)
                (out / ".built").touch()
        return out

    return get


@pytest.fixture
def served(request):
    """``ambdaq sim serve --profile spindle --rpm RPM --seed SEED`` in its own process (the test's
    indirect parameter: RPM, or (RPM, SEED); 30,000 rpm and seed 0 by default); yields the
    controller's ``serial://`` URL."""
    import subprocess
    import sys

    param = getattr(request, "param", 30000)
    rpm, seed = param if isinstance(param, tuple) else (param, 0)
    proc = subprocess.Popen([sys.executable, "-m", "ambdaq", "sim", "serve", "--profile", "spindle",
                             "--rpm", str(rpm), "--seed", str(seed), "--duration", "180"], stdout=subprocess.PIPE,
                            text=True)
    try:
        name, pty = proc.stdout.readline().split()
        assert name == "controller"
        yield f"serial://{pty}"
    finally:
        proc.terminate()
        proc.wait(timeout=10)


@pytest.fixture(scope="session")
def spindle_file(tmp_path_factory) -> Path:
    """2 s of the spindle at 30,000 rpm with ground truth, generated unpaced."""
    out = tmp_path_factory.mktemp("rec") / "spindle.mcap"
    result = CliRunner().invoke(
        cli, ["sim", "generate", "--duration", "2", "--rpm", "30000", "--truth", "-q", "-o", str(out)],
        catch_exceptions=False,
    )
    assert result.exit_code == 0, result.output
    return out



@pytest.fixture(scope="module")
def third_party_rig():
    """The spindle served in this process with the devices described by vendor files (a DBC
    probe conditioner, an EDS drive) on its CAN bus.  Module-scoped: held for one module's tests
    only, since the rig and the conditioner run threads that would load every later test."""
    from ambdaq.sim.serve import serve
    from ambdaq.speed import SpeedProfile

    served = serve("spindle", speed=SpeedProfile(30000, 30000), third_party=True)
    yield served
    served.stop()


@pytest.fixture(scope="session")
def chromium():
    """Debian's chromium; installed here if the machine lacks it and we may (root with apt-get), so
    the README's test command works on a fresh machine."""
    found = shutil.which("chromium")
    if found is None and os.geteuid() == 0 and shutil.which("apt-get"):
        env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
        subprocess.run(["apt-get", "update", "-qq"], check=True, capture_output=True, env=env, timeout=600)
        subprocess.run(["apt-get", "install", "-y", "-qq", "chromium"], check=True, capture_output=True, env=env,
                       timeout=900)
        found = shutil.which("chromium")
    assert found, "the report test needs Debian's chromium: apt-get install chromium"
    return found
