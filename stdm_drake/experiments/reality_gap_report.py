"""The reality-gap experiment's files, figures and report section (the experiment itself:
`experiments.reality_gap`)."""
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


def report_section(report, results: dict, folder: str = "reality_gap") -> None:
    """The reality-gap stage in a `Report`: the closed-loop table and verdict, the torque Jacobian errors,
    the per-effect open-loop table, and the figures (in `folder`, relative to the report)."""
    def g(value):
        return f"{value:.3g}"

    report.heading("Reality gap: learned models against the nominal model on the affected plant")
    closed_plans, seeds = results["closed_loop_plans"], results["design"]["closed"][3]
    report.text(f"Design: docs/reality_gap.md (run 2). Data: {closed_plans} plans tracked on the affected plant "
                "by PID with dither, gains sized from its inertia; D and DD models (`train`'s defaults), "
                f"{seeds} seeds each. Every prediction model's MPC setting (effort-weight scale, observer gain) "
                "is chosen on the validation plans; the test plans run with it ('tuned') and with the shipped "
                "controller settings ('shipped'). Ratio: nominal-model MPC q MSE / the model's (geometric mean "
                "over plans per seed; 95 % interval over seeds); above 1 the model tracks better.")
    report.table(["MPC settings", "model", "setting (effort scale / observer gain)", "q MSE (rad²)",
                  "nominal / model [95 % CI]", "steps outside the limits", "solve ms / step"],
                 [[row["setting"], row["model"], " ".join(f"{s:g}/{o:g}" for s, o in row["mpc_settings"]),
                   g(row["q_mse"]), g(row["nominal_over_model"]["ratio"]) + (
                       f" [{g(row['nominal_over_model']['low'])}, {g(row['nominal_over_model']['high'])}]"
                       if row["nominal_over_model"].get("low") is not None else ""),
                   row["limit_violations"], f"{row['solve_ms_mean']:.1f}"] for row in results["closed_loop"]])
    report.text(f"**Verdict** (goal: the best learned model's interval above 2, no limit violation): "
                f"{results['verdict']['text']}.")
    report.text("Torque Jacobian B = dx_k+1/du_k (what iLQR steers with), median relative error against the true "
                "plant's: " + ", ".join(f"{row['model']} {g(row['relative_error'])}" for row in results["torque_jacobian"])
                + ".")
    report.image(f"{folder}/closed_loop.png", "Closed loop on the affected plant: nominal MPC q MSE / each model's")
    report.table(["plant", "model", "one-step q MSE", "q MSE at step 20", "q MSE at the plan's end",
                  "beats the nominal (every seed: 1 / 20 / end)", "learned (vs physics-free, per seed)"],
                 [[row["plant"], row["model"], g(row["one_step_q"]), g(row["open_loop_q_20"]), g(row["open_loop_q_end"]),
                   " / ".join("yes" if v else "no" for v in row["beats_nominal_every_seed"].values())
                   if "beats_nominal_every_seed" in row else "",
                   ", ".join(row.get("learned", []))] for row in results["open_loop"]])
    report.text("Open loop per effect: the nominal model, the physics-free baselines (one step: the Euler step; "
                "open loop: the robot stays put) and each learned type (mean over seeds) stepping the recorded "
                "torques of the test plans of a plant with one effect at a time.")
    report.image(f"{folder}/open_loop.png", "Open-loop q MSE per effect")
