"""The reproduction report's figures (PNG, written atomically): Figs. 11/16 (activations), 12/17
(sample efficiency), 13 (learning curves) and 18/19 (multi-step errors)."""
import numpy as np

from stdm_drake.experiments.results import select_rows
from stdm_drake.files import atomic_path


def figure_path(folder, name):
    return folder / f"{name}.png"


def _save(figure, path):
    import matplotlib.pyplot as plt

    with atomic_path(path) as temp:
        figure.savefig(temp, format="png", dpi=100)
    plt.close(figure)


def plot_activations(rows, title, path):
    import matplotlib.pyplot as plt
    figure, axes = plt.subplots(1, 2, figsize=(12, 4))
    x = np.arange(len(rows))
    for axis, quantity, unit in zip(axes, ("q", "v"), ("rad²", "(rad/s)²")):
        axis.bar(x - 0.2, [r[f"{quantity}_naive"] for r in rows], 0.4, label="naive (D)")
        axis.bar(x + 0.2, [r[f"{quantity}_DD"] for r in rows], 0.4, label="derivative, alpha 1e-3 (our units) (DD)")
        for i, row in enumerate(rows):
            ratio = row[f"{quantity}_DD_ratio"]
            axis.annotate(f"{ratio['ratio']:.2g}x", (i, max(row[f"{quantity}_naive"], row[f"{quantity}_DD"])),
                          ha="center", va="bottom", fontsize=8, fontweight="bold" if ratio["verdict"] != "no clear "
                          "difference" else "normal")
        axis.set(xticks=x, xticklabels=[r["activation"] for r in rows], yscale="log",
                 ylabel=f"one-step test MSE ({unit})",
                 title=f"{title}: {'joint angles' if quantity == 'q' else 'velocities'} (naive/DD, bold: 95 % CI excludes 1)")
        axis.legend()
    figure.tight_layout()
    _save(figure, path)


def plot_sizes(rows, title, xlabel, path):
    import matplotlib.pyplot as plt
    figure, axes = plt.subplots(1, 2, figsize=(11, 4))
    sizes = [r["train_trajectories"] for r in rows]
    for axis, quantity in zip(axes, ("q", "v")):
        for key, label in (("naive", "naive (D)"), ("DD", "paper alpha (DD)"), ("DD-auto", "alpha by validation")):
            if f"{quantity}_{key}" not in rows[0]:
                continue
            axis.errorbar(sizes, [r[f"{quantity}_{key}"] for r in rows], yerr=[r[f"{quantity}_{key}_std"] for r in rows],
                          marker="o", capsize=4, label=label)
        axis.set(xlabel=xlabel, ylabel="one-step test MSE", yscale="log",
                 title=f"{title}: {'joint angles' if quantity == 'q' else 'velocities'} (swish, mean ± std over seeds)")
        axis.legend()
    figure.tight_layout()
    _save(figure, path)


def plot_learning_curves(results, size, path):
    import matplotlib.pyplot as plt
    figure, axis = plt.subplots(figsize=(7, 4.5))
    for model_type, color in (("D", "tab:blue"), ("DD", "tab:orange"), ("DD-auto", "tab:green")):
        for index, run in enumerate(select_rows(results, experiment="sim", model_type=model_type, activation="swish",
                                            train_size=size)):
            axis.semilogy(run.epoch_axis, run.val_mse_curve, color=color, alpha=0.6,
                          label=model_type if index == 0 else None)
    axis.set(xlabel="epoch", ylabel="validation state MSE (standardized)",
             title="validation curves, every seed (paired grids: one initialization per seed)")
    axis.legend()
    figure.tight_layout()
    _save(figure, path)


def plot_multistep(results, horizon, path):
    import matplotlib.pyplot as plt
    figure, axes = plt.subplots(1, 2, figsize=(12, 4))
    for run in select_rows(results, experiment="multistep"):
        steps = np.arange(1, len(run.multistep_q) + 1)[:horizon]
        style = "--" if run.model_type in ("DD", "PD", "DED", "PED") else "-"
        for axis, key in zip(axes, ("multistep_q", "multistep_v")):
            mean, std = np.array(getattr(run, key))[:horizon], np.array(getattr(run, f"{key}_std"))[:horizon]
            line, = axis.semilogy(steps, mean, style, label=run.model_type)
            axis.fill_between(steps, np.maximum(mean - std, 1e-12), mean + std, color=line.get_color(), alpha=0.1)
    for axis, name in zip(axes, ("joint angles (rad²)", "velocities ((rad/s)²)")):
        axis.set(xlabel="prediction step", ylabel=f"MSE, {name}", title=f"open-loop prediction, {horizon} steps")
        axis.legend(ncol=2, fontsize=8)
    figure.tight_layout()
    _save(figure, path)
