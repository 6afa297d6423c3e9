"""The Ray backend against a real Ray head started here on loopback (2 CPUs): the same rows and bitwise
the same checkpoints as the local pool (training jobs and the sine-sum study), a failing job's own error, a killed worker's job retried, and
one-line errors for an unreachable cluster."""
import dataclasses
import json
import os
import socket
import subprocess
import sys
import time

import secrets

import pytest
import torch

pytestmark = pytest.mark.slow   # each test joins a Ray head started for the module (seconds to start and stop)

# Token authentication, as a cluster should run: Ray reads the mode when it is imported, so the driver (this
# process) gets the token before `import ray`, and the head started below gets the same one.
AUTH = {"RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN": os.environ.get("RAY_AUTH_TOKEN") or secrets.token_hex(32)}
os.environ.update(AUTH)
ray = pytest.importorskip("ray")

from stdm_drake.errors import InputError  # noqa: E402
from stdm_drake.experiments.jobs import TrainJob, run_jobs  # noqa: E402
from stdm_drake.cluster import KILL_ONCE_VARIABLE, RunnerConfig  # noqa: E402

RAY = os.path.join(os.path.dirname(sys.executable), "ray")
TIMING = ("train_seconds", "rollout_ms", "reused")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def head(tmp_path_factory):
    """A Ray head on 127.0.0.1 with 2 CPUs and this module's token; its workers die once while the kill
    marker is missing."""
    marker = tmp_path_factory.mktemp("ray") / "killed-once"
    port = free_port()
    env = dict(os.environ, **AUTH, **{KILL_ONCE_VARIABLE: str(marker), "RAY_USAGE_STATS_ENABLED": "0"})
    subprocess.run([RAY, "start", "--head", "--node-ip-address=127.0.0.1", f"--port={port}", "--num-cpus=2",
                    "--include-dashboard=false", "--disable-usage-stats"], env=env, check=True,
                   capture_output=True, timeout=120)
    try:
        yield f"127.0.0.1:{port}", marker
    finally:
        if ray.is_initialized():
            ray.shutdown()
        subprocess.run([RAY, "stop", "--force"], env=env, capture_output=True, timeout=120)


def small_jobs(dataset_path) -> list[TrainJob]:
    from stdm_drake.data.dataset import load_dataset
    dataset = load_dataset(dataset_path)
    common = dict(experiment="sim", dataset=str(dataset_path), dataset_sha256=dataset.sha256, train=(0, 1), val=(2,),
                  test=(3,), activation="tanh", ensemble_size=1, max_epochs=3, patience=3, horizon=10, multistep=False,
                  train_size=2)
    return [TrainJob(model_type="D", seed=0, **common), TrainJob(model_type="DD", seed=1, **common),
            TrainJob(model_type="PE", seed=0, **dict(common, ensemble_size=2)),
            TrainJob(model_type="D", seed=0, alphas=(0.0, 1e-3), **common)]


def assert_close(actual, expected, where="runs"):
    """Equal structure and values, floats to 1e-5 relative (float32 inference)."""
    if isinstance(expected, dict):
        assert isinstance(actual, dict) and actual.keys() == expected.keys(), where
        for key in expected:
            assert_close(actual[key], expected[key], f"{where}.{key}")
    elif isinstance(expected, list):
        assert isinstance(actual, list) and len(actual) == len(expected), where
        for index, (a, e) in enumerate(zip(actual, expected)):
            assert_close(a, e, f"{where}[{index}]")
    elif isinstance(expected, float):
        assert actual == pytest.approx(expected, rel=1e-5), where
    else:
        assert actual == expected, where


def clean(rows):
    """Result rows (TrainingResults or their JSON) without the timing fields."""
    return [{key: value for key, value in (row if isinstance(row, dict) else dataclasses.asdict(row)).items()
             if key not in TIMING} for row in rows]


def test_ray_gives_the_local_results_bit_for_bit_and_retries_a_killed_worker(head, tmp_path, excitation_dataset):
    address, marker = head
    jobs = small_jobs(excitation_dataset)
    local = run_jobs(jobs, tmp_path / "local", workers=1, progress=False)
    assert not marker.exists()
    remote = run_jobs(jobs, tmp_path / "ray", workers=2, progress=False,
                      runner=RunnerConfig(backend="ray", ray_address=address, max_retries=2))
    assert marker.exists()                                    # one worker died mid-sweep, and its job was rerun
    assert clean(remote) == clean(local)
    files = sorted(path.name for path in (tmp_path / "local").iterdir())
    assert files == sorted(path.name for path in (tmp_path / "ray").iterdir()) and len(files) == 2 * len(jobs)
    for name in files:
        if name.endswith(".pt"):
            a = torch.load(tmp_path / "local" / name, weights_only=True)["weights"]
            b = torch.load(tmp_path / "ray" / name, weights_only=True)["weights"]
            assert a.keys() == b.keys() and all(torch.equal(a[key], b[key]) for key in a), name
    again = run_jobs(jobs, tmp_path / "ray", workers=2, progress=False,
                     runner=RunnerConfig(backend="ray", ray_address=address))
    assert all(row.reused for row in again) and clean(again) == clean(local)   # the same cache, reused


def test_a_job_that_raises_reports_its_own_error(head, tmp_path, excitation_dataset):
    address, _ = head
    bad = dataclasses.replace(small_jobs(excitation_dataset)[0], train=(0, 99))   # no trajectory 99
    with pytest.raises(InputError) as error:
        run_jobs([bad], tmp_path / "cache", workers=2, progress=False,
                 runner=RunnerConfig(backend="ray", ray_address=address))
    message = str(error.value)
    assert "training job 0 (sim D seed 0) on the cluster failed: trajectory index out of range" in message and "\n" not in message, message


def test_the_sine_sum_study_on_ray_equals_the_local_report(head, tmp_path):
    """`sine-sum --quick --backend ray` against the running head: the same runs as on the local pool (the quick
    profile at 300 steps; its 6000 run in `reproduce --quick`'s test). reproduce's training jobs on Ray are
    `test_ray_gives_the_local_results_bit_for_bit...`'s `run_jobs`, and `train --backend ray` is
    `test_train_seeds_on_ray_write_the_local_checkpoints`."""
    from stdm_drake.cli import main
    address, _ = head
    if ray.is_initialized():
        ray.shutdown()
    assert main(["sine-sum", "--quick", "--epochs", "300", "--quiet", "--backend", "ray", "--ray-address", address,
                 "-o", str(tmp_path / "ray")]) == 0
    assert main(["sine-sum", "--quick", "--epochs", "300", "--quiet", "--workers", "2", "-o", str(tmp_path / "local")]) == 0
    local, remote = (json.loads((tmp_path / name / "results.json").read_text())["runs"] for name in ("local", "ray"))
    assert len(remote) == len(local) > 0
    assert [run["member_test_mse"] for run in remote] == [run["member_test_mse"] for run in local]
    assert [run["best_prediction"] for run in remote] == [run["best_prediction"] for run in local]


def test_unreachable_cluster_and_missing_ray_are_one_line_errors(tmp_path, capsys, monkeypatch):
    from stdm_drake.cli import main
    if ray.is_initialized():
        ray.shutdown()
    started = time.perf_counter()
    assert main(["reproduce", "--quick", "--backend", "ray", "--ray-address", f"127.0.0.1:{free_port()}",
                 "-o", str(tmp_path / "out")]) == 2
    error = capsys.readouterr().err
    assert "cannot reach the Ray cluster" in error and error.count("\n") == 1
    assert time.perf_counter() - started < 30 and not (tmp_path / "out").exists()
    monkeypatch.setitem(sys.modules, "ray", None)            # as if Ray were not installed
    assert main(["reproduce", "--quick", "--backend", "ray", "-o", str(tmp_path / "out")]) == 2
    assert 'pip install -e ".[ray]"' in capsys.readouterr().err



def test_train_seeds_on_ray_write_the_local_checkpoints(head, tmp_path, excitation_dataset, capsys):
    """`train --seeds 0 1 2 --backend ray`: every seed trained on the cluster, the files written here,
    checkpoints bitwise equal to the local run's (a DD and a grey box G); --resume is refused with Ray."""
    from stdm_drake.cli import main
    address, _ = head
    common = ["train", str(excitation_dataset), "--model", "DD", "--epochs", "4", "--train", "2", "--val", "1",
              "--seeds", "0", "1", "2", "--quiet"]
    assert main(common + ["-o", str(tmp_path / "local")]) == 0
    assert main(common + ["--backend", "ray", "--ray-address", address, "-o", str(tmp_path / "ray")]) == 0
    for seed in (0, 1, 2):
        a = torch.load(tmp_path / "local" / f"seed{seed}" / "checkpoint.pt", weights_only=True)["weights"]
        b = torch.load(tmp_path / "ray" / f"seed{seed}" / "checkpoint.pt", weights_only=True)["weights"]
        assert all(torch.equal(a[key], b[key]) for key in a)
        curves = [[line.rsplit(",", 1)[0] for line in (tmp_path / name / f"seed{seed}" / "curves.csv").read_text()
                   .splitlines()] for name in ("local", "ray")]      # every column but the epoch's seconds
        assert curves[0] == curves[1]
    summary = json.loads((tmp_path / "ray" / "summary.json").read_text())
    assert sorted(summary["seeds"]) == ["0", "1", "2"]
    capsys.readouterr()
    assert main(common + ["--backend", "ray", "--resume", "-o", str(tmp_path / "ray")]) == 2
    assert "--resume continues runs in a local folder" in capsys.readouterr().err
    grey = ["train", str(excitation_dataset), "--model", "G", "--epochs", "2", "--train", "2", "--val", "1",
            "--seeds", "0", "1", "--quiet"]       # the grey box (plant-step inputs) on the cluster too
    assert main(grey + ["-o", str(tmp_path / "grey_local")]) == 0
    assert main(grey + ["--backend", "ray", "--ray-address", address, "-o", str(tmp_path / "grey_ray")]) == 0
    for seed in (0, 1):
        a = torch.load(tmp_path / "grey_local" / f"seed{seed}" / "checkpoint.pt", weights_only=True)["weights"]
        b = torch.load(tmp_path / "grey_ray" / f"seed{seed}" / "checkpoint.pt", weights_only=True)["weights"]
        assert all(torch.equal(a[key], b[key]) for key in a)


def test_the_decisive_experiment_runs_on_ray_with_the_local_results(head, tmp_path):
    """The decisive study's cells on the cluster: datasets collected by its workers and sent back, each
    once through the object store to the training tasks; the same rows as the local pool."""
    from stdm_drake.cluster import RunnerConfig
    from tools_import import decisive   # (tools/studies/decisive.py: its functions travel to the workers by value)
    address, _ = head
    options = dict(cells=decisive.CELLS[:1], data_seeds=1, inits=2, sizes=(6, 4, 6), max_epochs=5,
                   progress=lambda text: None)
    local = decisive.run_study(tmp_path / "local", RunnerConfig(workers=1), **options)
    remote = decisive.run_study(tmp_path / "ray", RunnerConfig(backend="ray", ray_address=address), **options)
    strip = lambda rows: [{k: v for k, v in dataclasses.asdict(row).items() if k != "train_seconds"}  # noqa: E731
                          for row in rows]
    assert_close(strip(remote["runs"]), strip(local["runs"]))
    assert (tmp_path / "ray" / "literal-10ms_seed0_n22.h5").read_bytes() == \
        (tmp_path / "local" / "literal-10ms_seed0_n22.h5").read_bytes()
