"""The files a training job writes beside each checkpoint: learning curves (curves.csv), the alpha grid's
validation curve (alpha_selection.csv, alpha_selection.png), and the seed's one-line report."""
from __future__ import annotations

import csv
import io
import pathlib

import numpy as np

from stdm_drake.files import atomic_path, line_text, write_text_atomic
from stdm_drake.learning.alpha_selection import AlphaSelection
from stdm_drake.learning.checkpoint import HISTORY_COLUMNS


def history_csv(history: dict) -> str:
    """Learning curves as CSV text (one row per epoch, HISTORY_COLUMNS)."""
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(HISTORY_COLUMNS)
    for values in zip(*(history[column] for column in HISTORY_COLUMNS)):
        writer.writerow([int(values[0])] + [f"{value:.9g}" for value in values[1:]])
    return buffer.getvalue()


def alpha_selection_csv(selection: AlphaSelection) -> str:
    """The alpha grid's validation curve as CSV: alpha, derivative_source (empty: the dataset's one source),
    val_state_mse_standardized, best_epoch, chosen."""
    lines = ["alpha,derivative_source,val_state_mse_standardized,best_epoch,chosen"]
    sources = selection.sources or ("",) * len(selection.alphas)
    for index, (alpha, source, score, epoch) in enumerate(zip(selection.alphas, sources, selection.val_mse,
                                                               selection.best_epochs)):
        source = source if alpha > 0 else ""   # (naive training sees no derivative targets)
        lines.append(f"{alpha:g},{source},{score:.9g},{int(epoch)},{int(index == selection.index)}")
    return "\n".join(lines) + "\n"


def plot_alpha_selection(selection: AlphaSelection, path, title: str = "") -> pathlib.Path:
    """Validation state MSE against alpha (log axes; alpha = 0 drawn as a dashed line) with the chosen entry
    starred where it is (naive: on its dashed line), and, where the grid held naive training, a second panel
    with the rule that chose: each alpha's 95 % lower bound of its gain over naive, which must be above 0 for
    that alpha to replace naive training. PNG, atomically."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    alphas, scores = np.asarray(selection.alphas), np.asarray(selection.val_mse)
    sources = np.asarray(selection.sources if selection.sources is not None else [""] * len(alphas))
    rule = selection.gain_low is not None
    figure, axes = plt.subplots(2 if rule else 1, 1, figsize=(5.5, 6.4 if rule else 3.8), sharex=True, squeeze=False)
    axis = axes[0, 0]
    positive = alphas > 0
    colors = dict(zip(dict.fromkeys(sources[positive]), ("tab:orange", "tab:green", "tab:purple", "tab:red")))
    for source, color in colors.items():
        rows = positive & (sources == source)
        axis.loglog(alphas[rows], scores[rows], "o-", color=color,
                    label="derivative learning" + (f" ({source} targets)" if source else ""))
    for score in scores[~positive]:
        axis.axhline(score, color="tab:blue", linestyle="--", label="naive (alpha = 0)")
    chosen = selection.label(selection.index)
    if selection.alpha > 0:
        axis.plot([selection.alpha], [scores[selection.index]], "k*", markersize=14, label=f"chosen: {chosen}")
    else:   # naive: on its line, at the left edge (alpha 0 has no place on a log axis)
        axis.plot([alphas[positive].min() if positive.any() else 1.0], [scores[selection.index]], "k*", markersize=14,
                  label="chosen: naive (alpha 0)")
    axis.set_ylabel("validation state MSE (standardized)")
    axis.set_title(title or "alpha chosen by validation")
    axis.legend(fontsize=8)
    if rule:
        bounds = 100.0 * np.asarray(selection.gain_low, dtype=float)
        rule_axis = axes[1, 0]
        for source, color in colors.items():
            rows = positive & (sources == source)
            rule_axis.semilogx(alphas[rows], bounds[rows], "o-", color=color)
        rule_axis.axhline(0.0, color="k", linewidth=0.8)
        rule_axis.set_ylabel("gain over naive, 95 % lower bound (%)")
        rule_axis.set_title("rule: an alpha replaces naive only where this bound is above 0\n(paired over the "
                            "validation trajectories); among those, the lowest MSE", fontsize=8)
    (axes[-1, 0]).set_xlabel("alpha (relative: each output's derivative residual over its target's spread)"
                             if selection.scale == "relative" else "alpha (paper eq. 9)")
    path = pathlib.Path(path)
    with atomic_path(path) as temp:
        figure.savefig(temp, format="png", dpi=110, bbox_inches="tight")
    plt.close(figure)
    return path


def write_seed_files(folder: pathlib.Path, name: str, seed: int, result, selection) -> dict:
    """A trained seed's learning curves and alpha selection (CSV, PNG) beside its checkpoint, one line
    printed; returns its summary entry."""
    write_text_atomic(folder / "curves.csv", history_csv(result.history))
    entry = dict(checkpoint=str(folder / "checkpoint.pt"), epochs=result.epochs_run, stopped_early=result.stopped_early,
                 best_epochs=result.best_epochs, best_val_mse_standardized=result.best_scores)
    if selection is not None:
        write_text_atomic(folder / "alpha_selection.csv", alpha_selection_csv(selection))
        plot_alpha_selection(selection, folder / "alpha_selection.png", title=f"{name} seed {seed}")
        entry["alpha_selection"] = selection.as_dict()
        lowest = int(np.argmin(selection.val_mse))
        kept = "" if lowest == selection.index else (   # (naive kept where the lowest one's gain is within the noise)
            f", though {selection.label(lowest)} had the lowest validation MSE, its gain within validation's noise (the bounds below)")
        print(f"seed {seed}: chosen by validation: {selection.label(selection.index)}{kept} (validation state MSE, "
              "standardized: " + "; ".join(f"{selection.label(i)} {v:.3g}" for i, v in enumerate(selection.val_mse))
              + ")")
        if selection.gain_low is not None:
            print(f"seed {seed}: gain over naive training, 95 % lower bound: " + "; ".join(
                f"{selection.label(i)} {100 * g:+.2g} %" for i, g in enumerate(selection.gain_low) if selection.alphas[i])
                + ("" if selection.alpha > 0 else " -> naive kept: no alpha > 0 beat it beyond validation's noise"))
        if 0.0 in selection.alphas and selection.alpha > 0:
            naive = selection.val_mse[selection.alphas.index(0.0)]
            chosen = selection.val_mse[selection.index]
            print(f"seed {seed}: {selection.label(selection.index)}: validation state MSE {chosen:.4g} against naive "
                  f"training's {naive:.4g}, a gain of {100 * (1 - chosen / naive):+.3g} %")
    print(f"seed {seed}: {result.epochs_run} epochs, best validation MSE (standardized) "
          f"{np.mean(result.best_scores):.4g} at epoch(s) {result.best_epochs} -> {line_text(folder / 'checkpoint.pt')}")
    return entry
