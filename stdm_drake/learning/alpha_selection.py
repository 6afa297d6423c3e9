"""Alpha by validation and `fit_model`, what `stdm-drake train` runs: an alpha grid trained as one stack
(`train_alpha_grid`), the choice over alphas and derivative sources (`select_alpha`, `AlphaSelection`), and one
model fitted at a given or chosen alpha with its checkpoint (`fit_model`). The stack and the trainer itself are
`learning.trainer`'s."""
from __future__ import annotations

import dataclasses
import pathlib
from typing import Callable

import numpy as np

from stdm_drake.errors import InputError
from stdm_drake.learning.checkpoint import CheckpointMetadata, load_checkpoint, save_checkpoint
from stdm_drake.learning.regression import RegressionData
from stdm_drake.learning.settings import DEFAULT_ALPHA_GRID, TrainingConfig
from stdm_drake.learning.trainer import TrainResult, train_model


@dataclasses.dataclass
class AlphaSelection:
    """Outcome of an alpha grid: per entry the alpha, the best validation state MSE (standardized, the mean over
    outputs of ((x̂ - x)/σ_y)²) and the epoch it was reached; `index` is the chosen entry. sources: per entry the
    derivative source of its targets when several were tried (`select_alpha` over a dict of data), else None."""
    alphas: tuple
    val_mse: list
    best_epochs: list
    index: int
    sources: tuple | None = None
    gain_low: list | None = None   # per entry: the 95 % lower bound of its gain over naive (`naive_gain_bounds`)
    scale: str = "raw"             # the alphas' scale (`settings.ALPHA_SCALES`)

    @property
    def alpha(self) -> float:
        return float(self.alphas[self.index])

    @property
    def source(self) -> str | None:
        """The chosen entry's derivative source (None: one source was tried)."""
        return None if self.sources is None else self.sources[self.index]

    def label(self, index: int) -> str:
        """Entry `index` as "alpha 0.001" ("relative alpha 1" on the relative scale) or, with several sources,
        "alpha 0.001, true targets"."""
        source = "" if self.sources is None or self.alphas[index] == 0 else f", {self.sources[index]} targets"
        scale = "relative " if self.scale == "relative" and self.alphas[index] > 0 else ""
        return f"{scale}alpha {self.alphas[index]:g}{source}"

    def as_dict(self) -> dict:
        values = dict(alphas=[float(a) for a in self.alphas], val_mse=[float(v) for v in self.val_mse],
                      best_epochs=[int(e) for e in self.best_epochs], chosen_alpha=self.alpha, chosen_index=self.index,
                      alpha_scale=self.scale)
        if self.sources is not None:
            values.update(sources=list(self.sources), chosen_source=self.source)
        if self.gain_low is not None:
            values.update(gain_over_naive_low=[float(value) for value in self.gain_low])
        return values

    @classmethod
    def from_dict(cls, values: dict) -> "AlphaSelection":
        return cls(alphas=tuple(values["alphas"]), val_mse=list(values["val_mse"]),
                   best_epochs=list(values["best_epochs"]), index=int(values["chosen_index"]),
                   sources=tuple(values["sources"]) if values.get("sources") is not None else None,
                   gain_low=list(values["gain_over_naive_low"]) if values.get("gain_over_naive_low") is not None
                   else None, scale=values.get("alpha_scale", "raw"))


def train_alpha_grid(model_config, training_config: TrainingConfig, train_data: RegressionData,
                     val_data: RegressionData, *, alphas=DEFAULT_ALPHA_GRID,
                     on_epoch: Callable[[dict], None] | None = None) -> tuple[TrainResult, AlphaSelection]:
    """One single-member network per alpha, trained as one stack from the same initial weights on the
    same minibatches (so member k equals training alphas[k] alone), and the selection: the lowest
    validation state MSE (ties go to the earlier alpha). model_config's ensemble_size is ignored.
    Returns the whole stack (member k: alphas[k]) and the selection."""
    alphas = tuple(float(a) for a in alphas)
    grid_config = dataclasses.replace(model_config, ensemble_size=len(alphas))
    grid_training = dataclasses.replace(training_config, alpha_grid=alphas, alpha=0.0)
    result = train_model(grid_config, grid_training, train_data, val_data, on_epoch=on_epoch)
    scores = np.asarray(result.best_scores)
    index = int(np.flatnonzero(scores == scores.min())[0])
    return result, AlphaSelection(alphas=alphas, val_mse=scores.tolist(), best_epochs=list(result.best_epochs),
                                  index=index, scale=training_config.alpha_scale)


def member_errors_by_group(model, data: RegressionData) -> np.ndarray:
    """Each member's validation state MSE (standardized, as the model's `eval_score`) per group of rows (the
    trajectories of `data.groups`), (E, G) float64, groups in sorted order."""
    errors = model.member_row_errors(model.standardize(data)).numpy()          # (E, N)
    _, group = np.unique(np.asarray(data.groups), return_inverse=True)
    counts = np.bincount(group)
    return np.stack([np.bincount(group, weights=row) / counts for row in errors])


def naive_gain_bounds(errors: np.ndarray, naive: int) -> np.ndarray:
    """Per entry, the 95 % lower bound (one-sided, Student t over the G validation trajectories, paired) of its
    relative gain over the naive entry: mean_g (e_naive,g - e_k,g) / mean_g e_naive,g. errors: (K, G) per-entry
    per-trajectory validation MSE; > 0: the entry beats naive training beyond validation's noise."""
    from scipy import stats
    differences = errors[naive][None, :] - errors                                      # (K, G)
    groups = errors.shape[1]
    spread = differences.std(axis=1, ddof=1) / np.sqrt(groups)
    low = differences.mean(axis=1) - stats.t.ppf(0.95, groups - 1) * spread
    return low / errors[naive].mean()


def data_by_source(data) -> dict:
    """`data` (RegressionData, or a dict derivative source -> RegressionData in order of preference) as a
    dict; a lone RegressionData is keyed None."""
    return dict(data) if isinstance(data, dict) else {None: data}


def select_alpha(model_config, training_config: TrainingConfig, train_data, val_data, *,
                 alphas=DEFAULT_ALPHA_GRID,
                 on_epoch: Callable[[dict], None] | None = None) -> tuple[TrainResult, AlphaSelection]:
    """Choose alpha by validation (`train_alpha_grid`) and return the chosen single-member model (its
    history is its grid's) with the selection. With 0 in `alphas` and validation data of 3 or more trajectories
    (`RegressionData.groups`), an alpha > 0 replaces naive training only where its gain over naive is above 0 at
    95 % confidence (`naive_gain_bounds`: paired over the validation trajectories), and among those the lowest
    validation MSE wins; otherwise, and without 0 or groups, the lowest validation MSE wins. Either way the chosen
    model is at least as good as naive training on validation (the rule: on average over its trajectories); that
    naive member is returned as the result's `naive`.

    train_data, val_data: RegressionData, or dicts derivative source -> RegressionData (same transitions,
    the derivative targets of each source; the same keys in both): then one grid per source, alpha 0 only
    in the first (its member does not see the targets), and the selection is over every (alpha, source)
    entry, ties going to the earlier entry."""
    trains, vals = data_by_source(train_data), data_by_source(val_data)
    if list(trains) != list(vals):
        raise InputError(f"training and validation data have different derivative sources: {list(trains)}, "
                         f"{list(vals)}")
    alphas = tuple(float(a) for a in alphas)
    grids, entries = [], []   # per source: (result, alphas tried); entries: (source, grid index, member)
    for position, source in enumerate(trains):
        tried = alphas if position == 0 else tuple(a for a in alphas if a > 0)
        if not tried:
            continue
        result, _ = train_alpha_grid(model_config, training_config, trains[source], vals[source], alphas=tried,
                                     on_epoch=on_epoch)
        grids.append((result, tried, source))
        entries += [(source, len(grids) - 1, member) for member in range(len(tried))]
    scores = np.asarray([grids[grid][0].best_scores[member] for _, grid, member in entries])
    index = int(np.flatnonzero(scores == scores.min())[0])
    # the first grid's members are the first entries, so alpha 0's member index is its entry index
    naive_entry = grids[0][1].index(0.0) if 0.0 in grids[0][1] else None
    groups = next(iter(vals.values())).groups
    gain_low = None
    if naive_entry is not None and groups is not None and len(np.unique(groups)) >= 3:
        per_grid = [member_errors_by_group(result.model, vals[source]) for result, _, source in grids]
        errors = np.stack([per_grid[grid][member] for _, grid, member in entries])
        gain_low = naive_gain_bounds(errors, naive_entry)
        clear = np.flatnonzero(gain_low > 0)
        index = int(clear[np.argmin(scores[clear])]) if len(clear) else naive_entry
    source, grid, member = entries[index]
    result = grids[grid][0]
    naive = grids[0][0].model.member(naive_entry) if naive_entry is not None else None
    selection = AlphaSelection(alphas=tuple(grids[g][1][m] for _, g, m in entries), val_mse=scores.tolist(),
                               best_epochs=[int(grids[g][0].best_epochs[m]) for _, g, m in entries], index=index,
                               sources=None if list(trains) == [None] else tuple(s for s, _, _ in entries),
                               gain_low=None if gain_low is None else gain_low.tolist(),
                               scale=training_config.alpha_scale)
    chosen = TrainResult(model=result.model.member(member), history=result.history,
                         best_epochs=[result.best_epochs[member]], best_scores=[result.best_scores[member]],
                         epochs_run=result.epochs_run, stopped_early=result.stopped_early, naive=naive)
    return chosen, selection


def fit_model(model_config, training_config: TrainingConfig, train_data, val_data, *,
              alpha_grid: tuple | None = None, checkpoint_path=None,
              checkpoint_every: int = 10, metadata: CheckpointMetadata | dict | None = None, resume: bool = False,
              on_epoch: Callable[[dict], None] | None = None) -> tuple[TrainResult, AlphaSelection | None]:
    """Train one model as `stdm-drake train` does, at the derivative-loss weight training_config.alpha
    (eq. 9), or, given `alpha_grid`, at the alpha `select_alpha` chooses from it by validation first: a
    single-member model is then the chosen grid member itself, an ensemble is trained at the chosen
    alpha. The selection is stored in the checkpoint's metadata (`alpha_selection`); resuming a run
    that chose its alpha reuses the stored selection.

    train_data, val_data: RegressionData, or (with alpha_grid) dicts derivative source -> RegressionData, of
    which the selection chooses the source too (`select_alpha`); the metadata's derivative_source is then the
    chosen one."""
    metadata = (dataclasses.replace(metadata) if isinstance(metadata, CheckpointMetadata)
                else CheckpointMetadata.from_dict(dict(metadata or {})))
    if alpha_grid is None and (isinstance(train_data, dict) or isinstance(val_data, dict)):
        raise InputError("data of several derivative sources need an alpha grid to choose among them")
    selection = None
    if alpha_grid is not None:
        stored = None
        if resume and checkpoint_path is not None and pathlib.Path(checkpoint_path).exists():
            stored = load_checkpoint(checkpoint_path)
        if stored is not None and stored.metadata.alpha_selection is None and stored.resume is not None:
            raise InputError(f"{checkpoint_path} was being trained at the fixed alpha {stored.training_config.alpha:g} "
                             "(before train chose alpha by validation by default); resume it with --alpha "
                             f"{stored.training_config.alpha:g}, or train it anew without --resume")
        if stored is not None and stored.metadata.alpha_selection is not None:
            selection = AlphaSelection.from_dict(stored.metadata.alpha_selection)
            if selection.scale != training_config.alpha_scale:
                raise InputError(f"{checkpoint_path} chose its alpha on the {selection.scale} scale; resume it with "
                                 f"--alpha-scale {selection.scale}, or train it anew without --resume")
            if stored.resume is None:  # a finished single-member selection: nothing left to train
                return TrainResult(model=stored.model, history=stored.history,
                                   best_epochs=list(selection.best_epochs[selection.index:selection.index + 1]),
                                   best_scores=[selection.val_mse[selection.index]],
                                   epochs_run=int(stored.history.get("epoch", [0])[-1] if stored.history.get("epoch")
                                                  else 0), stopped_early=False), selection
        else:
            chosen, selection = select_alpha(model_config, training_config, train_data, val_data, alphas=alpha_grid,
                                             on_epoch=on_epoch)
            resume = False
            if model_config.ensemble_size == 1:
                if selection.source is not None:
                    metadata.derivative_source = selection.source
                metadata.alpha_selection = selection.as_dict()
                if checkpoint_path is not None:
                    save_checkpoint(checkpoint_path, chosen.model,
                                    training_config=dataclasses.replace(training_config, alpha=selection.alpha),
                                    history=chosen.history, metadata=metadata)
                return chosen, selection
        metadata.alpha_selection = selection.as_dict()
        if selection.source is not None:     # (also when resuming: the stored selection's source)
            metadata.derivative_source = selection.source
        training_config = dataclasses.replace(training_config, alpha=selection.alpha)
        train_data, val_data = (data_by_source(data)[selection.source] for data in (train_data, val_data))
    result = train_model(model_config, training_config, train_data, val_data, checkpoint_path=checkpoint_path,
                         checkpoint_every=checkpoint_every, metadata=metadata, resume=resume, on_epoch=on_epoch)
    if selection is not None and stored is None:
        result.naive = chosen.naive    # the grid's naive single network, beside the ensemble trained at its alpha
    return result, selection
