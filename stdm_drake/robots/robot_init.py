"""`stdm-drake robot init`: the starting robot config of a description, written to its YAML (the rules:
`robots.starting_config`), with the options of `InitOptions`: masses from geometry into a copy of the description,
packages the rules do not find, and `--update` of a YAML written before, keeping the user's edits
(`robots.config_update`)."""
from __future__ import annotations

import dataclasses
import os
import pathlib

from stdm_drake.errors import InputError
from stdm_drake.files import line_text, write_text_atomic
from stdm_drake.robots.derived_limits import PROVISIONAL_EFFORT, derive_effort_limits
from stdm_drake.robots.description import SUFFIXES
from stdm_drake.robots.geometry_masses import MassesFromGeometry, geometry_masses, write_with_masses
from stdm_drake.robots.robot import Robot, RobotConfig, load_robot
from stdm_drake.robots.starting_config import (YAML_FIXES, relative_to, check_robot, find_packages, srdf_home,
                                               starting_config, starting_home)
from stdm_drake.robots.config_update import mark, read_for_update
from stdm_drake.paths import check_input_file


def config_yaml(config: RobotConfig, source: str, notes: list, derived: dict | None = None,
                chosen_home: bool = False) -> str:
    """The robot config YAML text of `config`, with a header naming the description `source` and the `notes`;
    derived: per limit field, the joints whose values robot init derived, and chosen_home: whether it chose home:
    those values are marked on their lines (`config_update`)."""
    derived = derived or {}
    lines = [f"# Robot config written by `stdm-drake robot init` from {line_text(source)} (fields: RobotConfig in",
             "# stdm_drake/robots/robot.py; how each was chosen: docs/guides/robots.md, 'A robot from a description').",
             "# Values marked 'derived' or 'chosen' were set by robot init; `robot init --update` sets them again and",
             "# keeps every value you edit (and what you add).",
             *[f"# NOTE: {line_text(note)}" for note in notes]]
    for field in ("name", "model", "package_paths", "weld_frame", "arm_joints", "locked_joints", "home",
                  "tool_frame", "srdf", "disabled_collisions", "position_limits", "velocity_limits", "effort_limits"):
        value = getattr(config, field)
        if value in ("", {}, [], None) and field != "weld_frame":
            continue
        if field.endswith("_limits"):   # (in the arm's joint order)
            order = {joint: index for index, joint in enumerate(config.arm_joints)}
            value = dict(sorted(value.items(), key=lambda item: order.get(item[0], len(order))))
        if derived.get(field):   # (one line per joint: each derived value carries its mark)
            lines.append(f"{field}:")
            lines += [f"  {joint}: {mark(limit)}" + (f"  # derived: {mark(limit)}" if joint in derived[field] else "")
                      for joint, limit in value.items()]
        else:
            lines.append(f"{field}: {mark(value)}" + (f"  # chosen: {mark(value)}" if field == "home" and chosen_home
                                                     else ""))
    return "\n".join(lines) + "\n"


@dataclasses.dataclass
class InitOptions:
    """`robot init`'s options: name (None: the description's), srdf (a MoveIt SRDF), force (replace existing
    outputs), masses (links without <inertial> get masses from their geometry, in a copy of the description beside
    the YAML: `geometry_masses`), packages (package name -> folder, for package:// URIs the rule of the module's
    docstring does not find), update (the output exists: keep its fields but the values robot init marked and the
    user left as they were, `config_update`)."""
    name: str | None = None
    srdf: pathlib.Path | None = None
    force: bool = False
    masses: MassesFromGeometry | None = None
    packages: dict = dataclasses.field(default_factory=dict)
    update: bool = False


def write_starting_config(model: pathlib.Path, output: pathlib.Path,
                          options: InitOptions | None = None) -> tuple[RobotConfig, list, str]:
    """`robot init`: write the starting config of description `model` to `output` (never over an input, nor over an
    existing file unless `options.force`, or `options.update` where it is one robot init wrote), with a home from
    `starting_home` unless the SRDF names one; returns (the config, notes, "" when it passes `check_robot`, else
    the one-line reason)."""
    options = options or InitOptions()
    srdf, masses = options.srdf, options.masses
    model = check_input_file(model, "model file")
    srdf = check_input_file(srdf, "srdf file") if srdf is not None else None
    if model.suffix.lower() == ".xacro":
        expanded = model.with_suffix("") if model.with_suffix("").suffix else model.with_suffix(".urdf")
        raise InputError(f"{model} is a xacro template: expand it first (`xacro {model} > {expanded}`; xacro: pip "
                         f"install xacro, or your ROS distribution's), then `stdm-drake robot init {expanded}`")
    if model.suffix.lower() not in SUFFIXES:
        raise InputError(f"model file {model}: a robot description is a .urdf or .sdf file (Drake's parsers)")
    if output.resolve() in {model.resolve(), *([srdf.resolve()] if srdf else [])}:
        raise InputError(f"--output {output} is an input file; choose another path")
    keep = {}
    if options.update:
        if options.force:
            raise InputError("--update keeps the edits in the existing output, --force would write over them: give one")
        if not output.is_file():
            raise InputError(f"--update: {output} is not a robot config to update (run robot init without --update)")
        keep = read_for_update(output)
    elif output.exists() and not options.force:
        raise InputError(f"--output {output} exists; choose another path, pass --force to replace it, or --update to "
                         "keep its edits")
    folder = output.absolute().parent
    if masses is None:
        return _write_starting_config(model, output, folder, options, model, [], keep)
    masses.validate()
    final = masses.copy_path(model, folder)
    if final.resolve() in {model.resolve(), output.resolve(), *([srdf.resolve()] if srdf else [])}:
        raise InputError(f"the description with masses would be written over an input or the output ({final}); "
                         "write the YAML into another folder")
    if final.exists() and not (options.force or options.update):
        raise InputError(f"{final} exists (the description with masses); choose another folder or pass --force")
    found = geometry_masses(model, find_packages(model, given=options.packages)[0], masses.density, masses.total_mass)
    copy = final.with_name(f"{final.name}.{os.getpid()}.urdf")   # (beside it: the relative mesh paths hold)
    try:
        write_with_masses(model, copy, found)
        return _write_starting_config(copy, output, folder, options, model, [masses.note(found, final)], keep, final)
    finally:
        copy.unlink(missing_ok=True)


def _write_starting_config(model, output, folder, options, original, notes, keep, final=None):
    """write_starting_config's work on description `model` (a copy with masses, to be renamed `final`, or the
    `original` itself), the fields `keep` of an existing YAML kept."""
    srdf = options.srdf
    if final is not None and "model" in keep:   # (the kept YAML names the copy: the copy being made now)
        keep = {field: value for field, value in keep.items() if field != "model"}
    config, more = starting_config(model, folder, options.name, srdf, packages_near=original,
                                   packages=options.packages, keep=keep)
    if "model" in keep and (folder / keep["model"]).resolve() != original.resolve():
        raise InputError(f"--update: {output} names model {keep['model']}, not {original}; update it with its own "
                         "description")
    notes = notes + more
    try:   # (before the home search: holding a home against gravity is checked against these)
        notes += derive_effort_limits(Robot(config, folder), config)
    except InputError:   # (a config that does not load yet: the check below gives the reason; no stand-in kept)
        config.effort_limits = {joint: value for joint, value in config.effort_limits.items()
                                if value != PROVISIONAL_EFFORT}
    derived = {field: set(getattr(config, field)) - set(keep.get(field, {})) for field in
               ("position_limits", "velocity_limits", "effort_limits")}
    named = srdf_home(srdf, config.arm_joints) if srdf is not None else None
    chosen_home = named is None and "home" not in keep
    if named is not None:   # (a named pose is kept as it is)
        config.home = named
    elif chosen_home:
        try:
            home, touching = starting_home(Robot(config, folder))
            config.disabled_collisions = sorted({tuple(pair) for pair in config.disabled_collisions + touching},
                                                key=str) if "disabled_collisions" in keep else touching
            config.disabled_collisions = [list(pair) for pair in config.disabled_collisions]
            if home is None:
                notes.append("no configuration near the middle of the ranges is free of self-collision: choose home")
            else:
                config.home = home
            if touching:
                notes.append(f"{len(touching)} link pairs touch in every configuration tried (by design): disabled")
        except InputError as error:   # (the check below gives the same reason as the command's error)
            notes.append(f"home not chosen: the config does not load yet ({error})")
    try:   # (checked before anything is written)
        check_robot(Robot(config, folder))
        problem = ""
    except InputError as error:
        problem = str(error)
    # a YAML that does not pass is written only where the fix goes into it (limits the file lacks, a home);
    # a description the checks refuse is one line, nothing written
    if problem and not any(note.startswith(YAML_FIXES) for note in notes):
        raise InputError(problem)
    if final is not None:
        os.replace(model, final)
        config.model = relative_to(final, folder)
    write_text_atomic(output, config_yaml(config, original.name, notes, derived, chosen_home))
    if not problem:
        check_robot(load_robot(output))   # (the file as written loads as the config did)
    return config, notes, problem
