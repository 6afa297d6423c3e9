"""What `stdm-drake reproduce`'s training jobs return: one TrainingResult per trained model (a row of
results.json's "runs", cached beside its checkpoint), and the selection the report's tables are made of."""
import dataclasses


@dataclasses.dataclass(frozen=True)
class TrainingResult:
    """One trained model's test metrics: a row of `results.json`'s "runs". A grid job yields one per
    variant (D, DD, DD-auto), every other job one. MSE in rad² (q) and (rad/s)² (v) on the job's test
    trajectories; the multi-step curves (H,) are per step of the open-loop horizon H (multistep jobs only).

    experiment, train_size: the job's labels; reused: read from the cache rather than trained by this run.
    key: the job's cache key (`<cache>/<key>.pt` is the checkpoint). alpha: the derivative weight of
    this model; alpha_selection: the validation choice (`AlphaSelection.as_dict`) when alpha was chosen.
    epoch_axis, val_mse_curve: the learning curve (epochs, validation MSE); best_epoch, val_mse: the kept
    epoch and its validation MSE (grid members). euler_q_mse, unchanged_v_mse: the Euler step's q and
    "velocity unchanged"'s v MSE on the same transitions; noise_floor_q/v: the sensor's noise variance
    (0 for an ideal sensor); stays_put_multistep_q: "the robot stays put" per step; rollout_ms: median
    time of one batch-1 rollout over the horizon.
    """
    experiment: str
    train_size: int
    key: str
    model_type: str
    activation: str
    seed: int
    train_trajectories: int
    alpha: float
    alpha_selection: dict | None
    train_seconds: float
    epochs: int
    epoch_axis: list
    val_mse_curve: list
    q_mse: float
    v_mse: float
    euler_q_mse: float
    unchanged_v_mse: float
    noise_floor_q: float
    noise_floor_v: float
    best_epoch: int | None = None
    val_mse: float | None = None
    multistep_q: list | None = None
    multistep_v: list | None = None
    multistep_q_std: list | None = None
    multistep_v_std: list | None = None
    stays_put_multistep_q: list | None = None
    rollout_ms: float | None = None
    reused: bool = False

    def stored(self) -> dict:
        """The row as the cache stores it: without the job's labels and the reuse mark."""
        row = dataclasses.asdict(self)
        for label in ("experiment", "train_size", "reused"):
            row.pop(label)
        return row

    @classmethod
    def from_stored(cls, row: dict, experiment: str, train_size: int, reused: bool) -> "TrainingResult":
        """A stored row with the job's labels; TypeError when its fields are not this class's."""
        return cls(**row, experiment=experiment, train_size=train_size, reused=reused)


def select_rows(results: list[TrainingResult], **conditions) -> list[TrainingResult]:
    """The results whose fields equal `conditions` (e.g. experiment="sim", model_type="DD")."""
    return [r for r in results if all(getattr(r, key) == value for key, value in conditions.items())]
