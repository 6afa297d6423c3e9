"""Shared test setup: offline Drake, small datasets collected once per session."""
import os
import pathlib
import subprocess
import sys

os.environ["DRAKE_ALLOW_NETWORK"] = "meshcat"  # a remote package fails at once; local Meshcat works
_OWN_CACHE = None
if "STDM_DRAKE_CACHE" not in os.environ:  # converted meshes go to a folder of this run, not the user's cache
    import tempfile
    _OWN_CACHE = os.environ["STDM_DRAKE_CACHE"] = tempfile.mkdtemp(prefix="stdm-drake-test-cache-")
# (under pytest-xdist the workers inherit the controller's STDM_DRAKE_CACHE: one cache, written atomically, that
# the controller removes once they are done)
_XDIST_WORKER = os.environ.get("PYTEST_XDIST_WORKER")   # "gw0", ... in a pytest-xdist worker, else None
if _XDIST_WORKER:   # the workers share the cores (CI's 2): one BLAS / OpenMP thread each, before numpy or torch loads
    for _variable in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[_variable] = "1"

import pytest  # noqa: E402

# Test modules that run on one pytest-xdist worker, one after the other (pyproject's addopts: `--dist loadgroup`,
# scheduled by pytest_xdist_make_scheduler below): the Ray tests (one Ray head on this machine at a time: its
# ports, and `ray stop --force` at the module's end stops every Ray process here) and the users of the session's
# regular install and its `reproduce --quick` report (test_ray_backend compares its report with it): built once,
# not on each worker. A test elsewhere that takes `quick_report` still passes: its worker builds its own copy.
_SHARED_WORKER_MODULES = {"test_ray_backend.py", "test_reproduce.py"}
_SHARED_WORKER_GROUP = "ray-and-quick-report"
# Test modules whose module-scoped fixtures collect data for seconds (40 excitation trajectories, a log to import, an
# identified robot, the C++ controller program): each kept on one worker, so that the fixture is built once, not once
# per worker (the fast tier built the dynamics models' dataset on both workers: 8.6 and 6.8 s; the suite built the
# controller program on both: 127 and 118 s of setup)
_ONE_WORKER_MODULES = {"test_dynamics_models.py", "test_import.py", "test_identification.py", "test_controller_program.py"}
_MAX_AUTO_WORKERS = 4


def pytest_addoption(parser, pluginmanager):
    """Without pytest-xdist (`-p no:xdist`, or not installed) its options in pyproject's addopts are accepted
    and ignored: the suite runs serially."""
    if not pluginmanager.has_plugin("xdist"):
        group = parser.getgroup("xdist", "pytest-xdist is off")
        # (_addoption, as xdist adds its own -n: pytest reserves lowercase short options to itself and plugins)
        group._addoption("-n", "--numprocesses", dest="numprocesses", default=None, help="(pytest-xdist is off)")
        group.addoption("--dist", dest="dist", default="no", help="(pytest-xdist is off)")


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_auto_num_workers(config):
    """`-n auto`: one worker per core, at most _MAX_AUTO_WORKERS (each holds its own Drake, torch and session
    datasets); PYTEST_XDIST_AUTO_NUM_WORKERS still decides when set."""
    if os.environ.get("PYTEST_XDIST_AUTO_NUM_WORKERS"):
        return None
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return max(1, min(cores, _MAX_AUTO_WORKERS))


def pytest_configure(config):
    if _XDIST_WORKER:
        import torch
        torch.set_num_threads(1)


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config, log):
    """`--dist loadgroup` with the tests of _SHARED_WORKER_MODULES as one group, by their node ids: an
    `xdist_group` mark does not group with pytest-xdist 3.8.0 on pytest 9.2 (it renames the node id through a
    field pytest no longer reads, pytest-xdist issue 1386). Larger groups are sent first (the shared group)."""
    if config.getvalue("dist") != "loadgroup":
        return None
    from xdist.scheduler import LoadGroupScheduling

    class SharedModulesScheduling(LoadGroupScheduling):
        def _split_scope(self, nodeid: str) -> str:
            module = nodeid.split("::", 1)[0].rsplit("/", 1)[-1]
            if module in _SHARED_WORKER_MODULES:
                return _SHARED_WORKER_GROUP
            if module in _ONE_WORKER_MODULES:
                return module
            return super()._split_scope(nodeid)

    return SharedModulesScheduling(config, log)


@pytest.fixture(scope="session")
def excitation_dataset(tmp_path_factory):
    """Path of a 4-trajectory excitation dataset (seed 3)."""
    from stdm_drake.cli import main
    path = tmp_path_factory.mktemp("data") / "excitation.h5"
    assert main(["collect", "--protocol", "excitation", "--count", "4", "--seed", "3", "--workers", "1",
                 "--quiet", "-o", str(path)]) == 0
    return path


@pytest.fixture(scope="session")
def tracking_dataset(tmp_path_factory):
    """Path of an 8-trajectory tracking dataset (2 per initial pose, seed 5)."""
    from stdm_drake.cli import main
    path = tmp_path_factory.mktemp("data") / "tracking.h5"
    assert main(["collect", "--protocol", "tracking", "--count", "8", "--seed", "5", "--workers", "1",
                 "--quiet", "-o", str(path)]) == 0
    return path


def closed_loop_status(rows) -> int:
    """The exit status `mpc` and `reproduce` owe for closed-loop result rows (dicts with
    limit_violations): 2 when any closed loop left the robot's limits, else 0. Tests whose tiny models
    may leave the limits check that the status follows the rows instead of assuming success."""
    return 2 if any(row["limit_violations"] for row in rows) else 0


def pytest_sessionfinish(session, exitstatus):
    session.config.stash[_EXIT_STATUS] = int(exitstatus)
    if _OWN_CACHE is not None:
        import shutil
        shutil.rmtree(_OWN_CACHE, ignore_errors=True)


@pytest.hookimpl(trylast=True)
def pytest_unconfigure(config):
    """Leave through os._exit once pytest has reported, with its exit status. In about one of three full
    runs on this 2-core machine the interpreter crashed (SIGSEGV) while finalizing, after every test had
    passed and the summary was printed: destructors of the native libraries loaded side by side (Drake,
    torch, Ray) at interpreter exit; no test was running. Skipping interpreter finalization keeps CI's
    status the tests' own; every test's files and processes are already closed by their fixtures."""
    status = config.stash.get(_EXIT_STATUS, None)
    if status is None:
        return
    coverage = sys.modules.get("coverage")   # under `coverage run`: save its data, which os._exit would skip
    measuring = coverage.Coverage.current() if coverage is not None else None
    if measuring is not None:
        measuring.stop()
        measuring.save()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(status)


_EXIT_STATUS = pytest.StashKey[int]()


ROOT = pathlib.Path(__file__).resolve().parents[1]


@pytest.fixture(scope="session")
def regular_install(tmp_path_factory):
    """A wheel built from the checkout, installed into a folder of its own: (environment that imports it without
    the checkout on the path, a working folder outside the checkout, the install folder). Its commands run as
    `python -S` with the dependencies' folder on PYTHONPATH: without `site`, the editable install's import hook
    (a .pth file) is not loaded, so a module the wheel lacks is an ImportError, not the checkout's copy."""
    wheels, target, work = (tmp_path_factory.mktemp(name) for name in ("wheels", "site", "work"))
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check", "-q"]
    from filelock import FileLock
    (ROOT / "build").mkdir(exist_ok=True)
    # setuptools builds in the checkout (build/, *.egg-info): one build at a time, should xdist workers outside
    # the shared group (another --dist) or another pytest run on this checkout build too
    with FileLock(str(ROOT / "build" / ".test-wheel.lock"), timeout=600):
        # (the compiled control step: setup.py copies the extension the editable install built in place where it is
        # up to date, else compiles it, a few minutes on 2 cores)
        subprocess.run(pip + ["wheel", "--no-deps", "--no-build-isolation", "-w", str(wheels), str(ROOT)], check=True,
                       cwd=work, timeout=900)
    (wheel,) = wheels.glob("stdm_drake-*.whl")
    subprocess.run(pip + ["install", "--no-deps", "--target", str(target), str(wheel)], check=True, timeout=300)
    dependencies = pathlib.Path(pytest.importorskip("numpy").__file__).parents[1]   # the venv's site-packages
    # Pinocchio's wheel (a cmeel package) lives under site-packages/cmeel.prefix, put on the path by a .pth file
    # that `python -S` skips: its folder goes on PYTHONPATH as site would put it
    import pinocchio
    rigid_body = pathlib.Path(pinocchio.__file__).parents[1]
    return (dict(os.environ, PYTHONPATH=os.pathsep.join([str(target), str(dependencies), str(rigid_body)]),
                 DRAKE_ALLOW_NETWORK="meshcat"), work, target)


@pytest.fixture(scope="session")
def quick_report(regular_install):
    """`reproduce --quick` (the README's main job on built-in defaults) run by the regular install: it finds the
    robot, plan and controller files inside the package (also the local run the Ray backend's must equal)."""
    env, work, _ = regular_install
    result = subprocess.run([sys.executable, "-S", "-m", "stdm_drake.cli", "reproduce", "--quick", "-o", "out", "--quiet"],
                            cwd=work, env=env, capture_output=True, text=True, timeout=900)
    assert result.returncode == 0, result.stderr[-2000:]
    return work / "out"
