"""`stdm-drake view`: a recorded trajectory and a learned model's open-loop prediction from the same
initial state and actions, side by side in Meshcat (the prediction as a translucent ghost; the job:
`closed_loop.replay`)."""
import pathlib

from stdm_drake.commands.arguments import add_robot_argument, add_visualization_argument
from stdm_drake.outputs import add_force_argument


def add_arguments(parser) -> None:
    parser.add_argument("checkpoint", type=pathlib.Path, metavar="MODEL",
                        help="trained model (checkpoint.pt) or identified robot (identified.yaml)")
    parser.add_argument("dataset", type=pathlib.Path, help="dataset with the trajectories to replay")
    parser.add_argument("--trajectories", type=int,
                        help="how many test trajectories (the checkpoint's test split when it was trained on "
                             "this dataset, else the dataset's last ones; default 3)")
    parser.add_argument("--index", type=int, action="append",
                        help="replay these trajectory indices instead (repeat the flag for several)")
    parser.add_argument("--html", type=pathlib.Path, help="save the recording as a standalone HTML file")
    parser.add_argument("--meshcat", action="store_true", help="play live in Meshcat (prints the URL)")
    add_robot_argument(parser, "must be the dataset's robot")
    add_visualization_argument(parser)
    add_force_argument(parser)


def run(args) -> int:
    from stdm_drake.closed_loop.replay import ReplayJob, replay_job
    replay_job(ReplayJob(model=args.checkpoint, dataset=args.dataset, trajectories=args.trajectories, index=args.index,
                         html=args.html, meshcat=args.meshcat, robot=args.robot, visualization=args.visualization,
                         force=args.force))
    return 0
