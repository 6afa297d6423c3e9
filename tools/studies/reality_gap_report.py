"""The reality-gap study's files and figures (the study itself: `studies.reality_gap`)."""
import pathlib

import numpy as np


def _table(rows: list) -> str:
    """CSV of rows with different keys: every key a column, empty where a row lacks it."""
    from stdm_drake.files import rows_csv
    columns = list(dict.fromkeys(key for row in rows for key in row))
    return rows_csv([{column: row.get(column, "") for column in columns} for row in rows], columns)


def write_results(results: dict, folder: pathlib.Path) -> None:
    """results.json (every run), closed_loop.csv, open_loop.csv and the two figures
    (closed_loop.png, open_loop.png) in `folder`, each written atomically."""
    import json
    from stdm_drake.files import json_default, write_text_atomic
    folder = pathlib.Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    flat = [dict({k: v for k, v in row.items() if k not in ("nominal_over_model", "mpc_settings")},
                 mpc_settings=" ".join(f"{scale:g}/{gain:g}" for scale, gain in row["mpc_settings"]),
                 **{f"nominal_over_model_{k}": v for k, v in row["nominal_over_model"].items()})
            for row in results["closed_loop"]]
    write_text_atomic(folder / "closed_loop.csv", _table(flat))
    open_flat = [dict({k: v for k, v in row.items() if k not in ("learned", "beats_nominal_every_seed")},
                      **{f"beats_nominal_{k}": v for k, v in row.get("beats_nominal_every_seed", {}).items()})
                 for row in results["open_loop"]]
    write_text_atomic(folder / "open_loop.csv", _table(open_flat))
    write_text_atomic(folder / "results.json", json.dumps(results, default=json_default) + "\n")
    plot_closed_loop(results, folder / "closed_loop.png")
    plot_open_loop(results, folder / "open_loop.png")


def plot_closed_loop(results: dict, path) -> None:
    """Per model and MPC setting: nominal MPC q MSE / the model's (learned: seed geometric mean with its
    95 % interval), log scale, the goal (2) and parity (1) marked (PNG)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from stdm_drake.files import atomic_path
    figure, axis = plt.subplots(figsize=(8, 4))
    for offset, setting in ((-0.2, "tuned"), (0.2, "shipped")):
        rows = [row for row in results["closed_loop"] if row["setting"] == setting]
        x = np.arange(len(rows)) + offset
        ratio = np.array([row["nominal_over_model"]["ratio"] for row in rows])
        low = np.array([row["nominal_over_model"].get("low") or r for row, r in zip(rows, ratio)])
        high = np.array([row["nominal_over_model"].get("high") or r for row, r in zip(rows, ratio)])
        axis.bar(x, ratio, width=0.4, label=f"MPC settings: {setting}")
        axis.errorbar(x, ratio, yerr=[ratio - low, high - ratio], fmt="none", color="k", capsize=3)
        axis.set_xticks(np.arange(len(rows)), [row["model"] for row in rows])
    axis.axhline(1.0, color="gray", lw=1)
    axis.axhline(2.0, color="green", lw=1, ls="--", label="goal: 2x")
    axis.set(yscale="log", ylabel="nominal MPC q MSE / model's", title="Closed loop on the affected plant (test plans)")
    axis.legend()
    figure.tight_layout()
    with atomic_path(path) as temp:
        figure.savefig(temp, format="png", dpi=110)
    plt.close(figure)


def plot_open_loop(results: dict, path) -> None:
    """Per effect plant: q MSE one step, at step 20 and at the plan's end of the nominal model, the
    physics-free baselines and each learned type (log scale, PNG)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from stdm_drake.files import atomic_path
    plants = list(dict.fromkeys(row["plant"] for row in results["open_loop"]))
    keys = (("one_step_q", "one step"), ("open_loop_q_20", "step 20"), ("open_loop_q_end", "plan's end"))
    figure, axes = plt.subplots(1, len(plants), figsize=(3.2 * len(plants), 3.6), sharey=True, squeeze=False)
    for axis, plant in zip(axes[0], plants):
        rows = [row for row in results["open_loop"] if row["plant"] == plant]
        for index, row in enumerate(rows):
            label = "physics-free" if row["model"].startswith("Euler") else row["model"]
            axis.bar(np.arange(len(keys)) + (index - len(rows) / 2 + 0.5) * 0.2, [row[k] for k, _ in keys], width=0.2,
                     label=label)
        axis.set_xticks(np.arange(len(keys)), [name for _, name in keys])
        axis.set(yscale="log", title=plant)
    axes[0][0].set_ylabel("open-loop q MSE (rad²)")
    handles, labels = axes[0][0].get_legend_handles_labels()
    figure.legend(handles, labels, loc="upper center", ncol=len(labels), fontsize=8)
    figure.tight_layout(rect=(0, 0, 1, 0.9))
    with atomic_path(path) as temp:
        figure.savefig(temp, format="png", dpi=110)
    plt.close(figure)
