"""The toolbox's own default model in `stdm-drake reproduce`, beside the paper's black box: its training jobs
(`train`'s default structure, alpha scale and grid on the excitation data; D against DD with alpha by validation,
paired by seed; `jobs.run_job` trains and tests them like any grid job)."""
from stdm_drake.experiments.jobs import Profile, TrainJob
from stdm_drake.data.dataset import split_trajectories
from stdm_drake.learning.settings import TrainSettings


def default_model_jobs(profile: Profile, excitation, robot_config: str) -> list[TrainJob]:
    """One grid job per seed (`profile.default_model_seeds`) on the excitation data's largest simulated split, with
    `train`'s default structure, activation, alpha scale, alpha grid (0 included) and patience."""
    defaults = TrainSettings()
    largest = max(profile.sim_train_sizes)
    jobs = []
    split = split_trajectories(excitation.groups, largest, profile.sim_val, profile.sim_test, seed=0, per_group=False)
    for seed in range(profile.default_model_seeds):
        jobs.append(TrainJob("default_model", str(excitation.path), excitation.sha256, tuple(split.train.tolist()),
                             tuple(split.val.tolist()), tuple(split.test.tolist()), "D", defaults.activation, seed,
                             multistep=True, train_size=largest, horizon=len(excitation.trajectory(0).tau),
                             alphas=tuple(sorted({0.0, *defaults.grid()})), structure="default",
                             robot_config=robot_config, alpha_scale=defaults.alpha_scale,
                             ensemble_size=profile.ensemble_size, max_epochs=profile.default_model_epochs,
                             patience=defaults.patience))
    return jobs
