"""Training one model per seed on the one pool (`cluster.job_pool`), as `stdm-drake train` does: a
dataset's split by the training settings, each seed's fit in this process (its epoch bar, its resumable
checkpoint) or on Ray (the checkpoint's bytes sent back)."""
from __future__ import annotations

import pathlib


from stdm_drake.devices import compute_threads
from stdm_drake.files import atomic_path
from stdm_drake.learning.settings import TrainSettings
from stdm_drake.learning.alpha_selection import fit_model
from stdm_drake.cluster import RunnerConfig, job_pool, shared, task_error


def fit_seed(model_config, training_config, train_data, val_data, fit_options: dict, threads: int,
             checkpoint_path: pathlib.Path | None = None, progress: str | None = None):
    """One seed of `train` in a pool's worker: fit_model with `threads` torch threads. With checkpoint_path
    (this machine) it trains into that file, resuming it when it exists, with a per-epoch progress bar
    labelled `progress`; returns (result, selection, None). Without (a Ray worker) it trains into a
    scratch file and returns its bytes third."""
    import shutil
    import tempfile

    from tqdm import tqdm
    compute_threads(threads)
    if checkpoint_path is not None:
        resume = checkpoint_path.exists()  # (only with --resume: checked before any work)
        bar = tqdm(total=training_config.max_epochs, desc=progress, unit="epoch", disable=progress is None,
                   dynamic_ncols=True)

        def on_epoch(row):
            bar.update(row["epoch"] - bar.n)
            bar.set_postfix(train=f"{row['train_loss']:.3g}", val_mse=f"{row['val_mse']:.3g}")

        try:
            result, selection = fit_model(model_config, training_config, train_data, val_data,
                                          checkpoint_path=checkpoint_path, resume=resume, on_epoch=on_epoch,
                                          **fit_options)
        finally:
            bar.close()
        return result, selection, None
    scratch = pathlib.Path(tempfile.mkdtemp(prefix="stdm-drake-seed-"))
    try:
        result, selection = fit_model(model_config, training_config, train_data, val_data,
                                      checkpoint_path=scratch / "checkpoint.pt", **fit_options)
        return result, selection, (scratch / "checkpoint.pt").read_bytes()
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


def fit_seeds(problem, settings: TrainSettings, fit_options: dict, runner, output: pathlib.Path, quiet: bool):
    """Train every seed of `settings` on the one pool (`cluster.job_pool`): in this process, one after
    another (each with its epoch bar), or all at once on Ray (one bar over the seeds, the checkpoints
    written here as they come back). Yields (seed, result, selection) as each finishes."""
    from tqdm import tqdm

    remote = runner.backend == "ray"
    name = settings.model_name()
    bar = tqdm(total=len(settings.seeds), desc=f"train {name} (ray)", unit="seed", disable=quiet or not remote)
    with job_pool(runner if remote else RunnerConfig(workers=1)) as pool:
        train_data, val_data = shared(pool, problem.train), shared(pool, problem.val)  # on Ray: once, not per seed
        calls = [(fit_seed, (problem.model_config, settings.training_config(seed), train_data, val_data, fit_options,
                             settings.threads) + (() if remote else (output / f"seed{seed}" / "checkpoint.pt",
                                                                      None if quiet else f"train {name} seed {seed}")))
                 for seed in settings.seeds]
        for position, future in pool.completed(calls):
            seed = settings.seeds[position]
            try:
                result, selection, checkpoint = future.result()
            except Exception as error:
                if not remote:
                    raise
                raise task_error(error, f"seed {seed} on the cluster") from None
            if checkpoint is not None:
                with atomic_path(output / f"seed{seed}" / "checkpoint.pt") as temp:
                    temp.write_bytes(checkpoint)
            bar.update()
            yield seed, result, selection
    bar.close()
