"""Shared test setup: offline Drake, small datasets collected once per session."""
import os
import sys

os.environ["DRAKE_ALLOW_NETWORK"] = "meshcat"  # a remote package fails at once; local Meshcat works
_OWN_CACHE = None
if "STDM_DRAKE_CACHE" not in os.environ:  # converted meshes go to a folder of this run, not the user's cache
    import tempfile
    _OWN_CACHE = os.environ["STDM_DRAKE_CACHE"] = tempfile.mkdtemp(prefix="stdm-drake-test-cache-")

import pytest  # noqa: E402


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
