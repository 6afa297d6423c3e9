"""`stdm-drake robot init MODEL`: a starting robot config YAML from a URDF or SDF, checked; `stdm-drake robot
check ROBOT.yaml`: the checks of a robot config before any work (`robots.starting_config`)."""
from __future__ import annotations

import argparse
import pathlib
import sys

from stdm_drake.errors import InputError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    actions = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    init = actions.add_parser("init", help="write a starting robot config YAML from a URDF or SDF and check it")
    init.add_argument("model", type=pathlib.Path, help="the robot's description file (.urdf or .sdf), as shipped")
    init.add_argument("--output", "-o", type=pathlib.Path,
                      help="robot config YAML to write (default: NAME.yaml in the working folder)")
    init.add_argument("--name", help="the robot's name (default: the name the description gives, else the model "
                                     "file's stem)")
    init.add_argument("--srdf", type=pathlib.Path,
                      help="a MoveIt SRDF: its disabled collision pairs, and home from a group state named home, "
                           "ready, zero or default")
    init.add_argument("--force", action="store_true", help="replace an existing output file")
    init.add_argument("--update", action="store_true",
                      help="bring an existing output that robot init wrote up to date with the description: every "
                           "value you edited or added is kept; the values robot init derived or chose and you left "
                           "as they were are set again")
    init.add_argument("--package", action="append", default=[], metavar="NAME=FOLDER",
                      help="the folder of package NAME, for package:// URIs that robot init does not find beside the "
                           "file (written to package_paths; repeat for several)")
    init.add_argument("--masses-from-geometry", action="store_true",
                      help="give each link without <inertial> the mass properties of a solid filling its collision "
                           "(else visual) geometry: boxes, cylinders, spheres, STL and OBJ meshes (URDF only); "
                           "written into a copy, NAME_masses.urdf beside the YAML, which the YAML names; the "
                           "dynamics are approximate")
    init.add_argument("--density", type=float, metavar="KG_PER_M3",
                      help="with --masses-from-geometry: the solids' density (default 1300 kg/m^3, between the "
                           "shipped UR-10's and Panda's own)")
    init.add_argument("--total-mass", type=float, metavar="KG",
                      help="with --masses-from-geometry: the masses scaled to sum to this, instead of a density")
    check = actions.add_parser("check", help="load a robot config and check it: limits, M(home), self-collision, "
                                             "gravity at home within the effort limits")
    check.add_argument("robot", type=pathlib.Path, help="robot config YAML")


def run(args: argparse.Namespace) -> int:
    from stdm_drake.files import line_text
    from stdm_drake.robots.robot import load_robot
    from stdm_drake.robots.starting_config import check_robot
    if args.action == "check":
        robot = load_robot(args.robot)
        for line in check_robot(robot):
            print(line_text(line))
        print(f"robot {line_text(robot.name)}: loads, {robot.num_joints} arm joints, home free of self-collision and held "
              "within the effort limits")
        return 0
    return init(args)


def init(args: argparse.Namespace) -> int:
    from stdm_drake.files import line_text
    from stdm_drake.robots.geometry_masses import MassesFromGeometry
    from stdm_drake.robots.robot_init import InitOptions, write_starting_config
    from stdm_drake.robots.starting_config import given_packages
    if args.name is not None and (not args.name.strip() or args.name in (".", "..")
                                  or pathlib.Path(args.name).name != args.name or "\\" in args.name
                                  or not args.name.isprintable()):   # (a line break would be in the YAML's file name)
        raise InputError(f"--name {args.name!r}: the robot's name, not a path, printable characters only (-o/--output "
                         "says where the YAML goes)")
    output = args.output or pathlib.Path(f"{args.name or args.model.stem}.yaml")
    masses = MassesFromGeometry.from_options(args.masses_from_geometry, args.density, args.total_mass)
    packages = given_packages(args.package)
    config, notes, problem = write_starting_config(
        args.model, output, InitOptions(args.name, args.srdf, args.force, masses, packages, args.update))
    print(f"wrote {line_text(output)}: {len(config.arm_joints)} arm joints ({line_text(', '.join(config.arm_joints))}), "
          f"{len(config.locked_joints)} locked, tool frame {line_text(config.tool_frame)}")
    for note in notes:
        print(f"note: {line_text(note)}")
    if problem:
        print(f"stdm-drake robot init: {line_text(output)} does not pass its check yet: {line_text(problem)}",
              file=sys.stderr)
        return 1
    print(f"{line_text(output)} passes its check (stdm-drake robot check {line_text(output)})")
    return 0
