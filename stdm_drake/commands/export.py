"""`stdm-drake export`: a trained model for use outside Python: ONNX graphs (the model and its Jacobians) for ONNX
Runtime, TensorRT or any ONNX backend, a Drake-native model file (Drake's MultilayerPerceptron systems) for a
Drake diagram in C++ or Python, or the MPC controller's file for the compiled controller program
(`stdm_drake.deploy`)."""
import argparse
import pathlib

from stdm_drake.outputs import add_force_argument


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("checkpoint", type=pathlib.Path, metavar="CHECKPOINT",
                        help="model checkpoint written by `stdm-drake train` (.pt)")
    parser.add_argument("--output", "-o", type=pathlib.Path, required=True,
                        help="file to write: model.onnx (and model.jacobian.onnx beside it) for --target onnx, "
                             "model.yaml for --target drake, mpc.controller for --target controller")
    parser.add_argument("--target", choices=("onnx", "drake", "controller"), default="onnx",
                        help="onnx (default): every model stdm-drake trains; drake: Drake's MultilayerPerceptron, for "
                             "models trained with --activation tanh or relu; controller: the MPC (model, settings, "
                             "limits) for the compiled controller program (docs/guides/deploy.md)")
    parser.add_argument("--robot", type=pathlib.Path,
                        help="controller: the robot config YAML the model was trained for (default: the UR-10's)")
    parser.add_argument("--config", type=pathlib.Path,
                        help="controller: the MPC settings YAML (default: controllers/mpc.yaml)")
    parser.add_argument("--mean-only", action="store_true",
                        help="onnx: the model graph gives next_state alone, without an ensemble's or P model's variance "
                             "and member outputs (ONNX Runtime runs the whole graph each call: a PE's step is a quarter "
                             "faster without them)")
    add_force_argument(parser)


def run(args: argparse.Namespace) -> int:
    from stdm_drake.errors import InputError
    if args.target == "controller":      # (the MPC's file: closed_loop, the stage that holds the controller)
        if args.mean_only:
            raise InputError("--mean-only belongs to the onnx target (the controller uses the model's mean)")
        from stdm_drake.closed_loop.controller_file import export_controller
        export_controller(args.checkpoint, args.output, args.robot, args.config, force=args.force)
        return 0
    if args.robot is not None or args.config is not None:
        raise InputError("--robot and --config belong to the controller target (the model's own file needs neither)")
    from stdm_drake.deploy.export_job import ExportJob, export_job
    export_job(ExportJob(checkpoint=args.checkpoint, output=args.output, target=args.target,
                          mean_only=args.mean_only, force=args.force))
    return 0
