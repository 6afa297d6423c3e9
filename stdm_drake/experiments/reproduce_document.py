"""`stdm-drake reproduce`'s report assembled: its sections in order (the opening from `reproduce_summary`, the paper's
sections from `reproduce_report`) and the result files behind it."""
import dataclasses
import json
import pathlib

from stdm_drake.experiments import reproduce_summary as summary
from stdm_drake.experiments.jobs import Profile
from stdm_drake.experiments.reproduce_report import (PAPER, _flat, add_coverage_sections, add_data_section,
                                                     add_mpc_section, add_multistep_section, add_simulated_sections,
                                                     add_sine_sum_section, add_tracked_sections)
from stdm_drake.files import json_default, write_text_atomic
from stdm_drake.provenance import results_header
from stdm_drake.report import Report


def write_result_files(folder: pathlib.Path, report, tables: dict, results) -> None:
    """report.md, report.html, results.json (tables and every run) and one CSV per table, atomically."""
    markdown, page = report.markdown(), report.html()
    write_text_atomic(folder / "report.md", markdown + "\n")
    write_text_atomic(folder / "report.html", page + "\n")
    write_text_atomic(folder / "results.json", json.dumps(dict(**results_header(), tables=tables, runs=results),
                                                           default=json_default))
    for name in ("default_model", "sim_activations", "sim_sizes", "real_activations", "real_sizes", "coverage", "mpc",
                 "mpc_runs"):
        rows = [_flat(row) for row in tables[name]]
        if rows:
            columns = list(dict.fromkeys(key for row in rows for key in row))
            write_text_atomic(folder / f"{name}.csv", "\n".join(
                [",".join(columns)] + [",".join(str(row.get(key, "")) for key in columns) for row in rows]) + "\n")


def write_report(folder: pathlib.Path, profile: Profile, excitation, local, tracking, identification, results, sine,
                 mpc_rows, timings: dict, *, robot, identification_controller: pathlib.Path) -> pathlib.Path:
    """The report of a reproduction run for `robot` in `folder`, section by section, with the result files behind
    it; returns the HTML page's path. identification_controller: the controller file the identification data
    were tracked with."""
    figures = folder / "figures"
    report = Report(f"stdm-drake reproduction of Kim, Lee & Ryu (IEEE Access 2022), profile '{profile.name}', "
                    f"robot {robot.name}")
    if robot.default_file("excitation") is None:   # (a robot config without protocol files of its own)
        report.text(f"Robot: {robot.name} ({robot.num_joints} joints), with the excitation "
                    "ranges, tracking poses, PID gains and MPC weights derived from its model (docs/guides/robots.md, 'Using your "
                    "own robot'). The 'paper' columns quote the paper's UR-10 numbers for scale, not as a target.")
    report.text("Every number below is computed by this run except the columns labelled 'paper', which quote "
                "the values stated in the paper's text. MSE in rad² (joint angles, q) and (rad/s)² (velocities, v); "
                "improvement = (MSE_naive - MSE_derivative) / MSE_derivative x 100 (the paper's definition). "
                f"Stage times (s): {', '.join(f'{k} {v:.0f}' for k, v in timings.items())}.")
    default_row = summary.default_model_row(results)
    summary.add_summary_section(report, results, sine, default_row, profile)
    add_data_section(report, excitation, local, tracking, identification, pathlib.Path(identification_controller).name)
    summary.add_default_model_section(report, default_row)
    sim_rows, sim_sizes = add_simulated_sections(report, results, profile, figures, robot.name)
    real_rows, real_sizes = add_tracked_sections(report, results, profile, figures)
    coverage = add_coverage_sections(report, results, profile)
    multistep = add_multistep_section(report, results, profile, figures)
    add_sine_sum_section(report, sine)
    add_mpc_section(report, mpc_rows)
    tables = dict(sim_activations=sim_rows, sim_sizes=sim_sizes, real_activations=real_rows, real_sizes=real_sizes,
                  coverage=coverage, default_model=[default_row] if default_row else [],
                  multistep=[{k: v for k, v in dataclasses.asdict(r).items() if k not in ("epoch_axis", "val_mse_curve")}
                             for r in multistep],
                  mpc=mpc_rows["types"] if mpc_rows else [], mpc_runs=mpc_rows["runs"] if mpc_rows else [],
                  paper=PAPER, profile=dataclasses.asdict(profile), stage_seconds=timings)
    write_result_files(folder, report, tables, results)
    return folder / "report.html"
