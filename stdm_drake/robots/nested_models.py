"""The robot's model instances in a plant: the one its file adds and the models nested in it (an SDF model's inner
or <include>d models, "arm::tool", a tool welded to the arm). Used by `robots.robot` (loading and checking the
robot) and `robots.plant` (its collision filters)."""
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import ModelInstanceIndex

from stdm_drake.errors import InputError


def robot_instance(plant: MultibodyPlant, instances, where: str, added_from: int | None = None):
    """The robot's model instance among the `instances` Drake's parser added for its one file: the first, the others
    nested in it (an SDF model's <include>d or inner models, "arm::tool": part of the robot, their joints fixed:
    `check_nested_fixed`). InputError (one line, `where`: the robot and file) for a file of several models side by
    side, or of none. added_from: the plant's count of instances before the parse, whose new ones stand in for an
    empty `instances` (an SDF world that <include>s a URDF: Drake adds its model and returns none)."""
    if not instances and added_from is not None:
        instances = [ModelInstanceIndex(index) for index in range(added_from, plant.num_model_instances())]
    names = [plant.GetModelInstanceName(instance) for instance in instances]
    if not names or any(not name.startswith(names[0] + "::") for name in names[1:]):
        raise InputError(f"{where} holds {len(names)} models ({', '.join(names[:5])}), expected one (with the models "
                         "nested in it)")
    return instances[0]


def nested_instances(plant: MultibodyPlant, instance) -> list:
    """The model instances nested in the robot's `instance` (an SDF's inner or <include>d models: "arm::tool")."""
    prefix = plant.GetModelInstanceName(instance) + "::"
    return [index for index in map(ModelInstanceIndex, range(plant.num_model_instances()))
            if plant.GetModelInstanceName(index).startswith(prefix)]


def check_nested_fixed(plant: MultibodyPlant, instance, where: str) -> None:
    """After Finalize: InputError where a model nested in the robot's `instance` moves (a joint of its own, or no
    joint to the arm at all): the robot's state is its own joints'."""
    for nested in nested_instances(plant, instance):
        if count := plant.num_velocities(nested):
            raise InputError(f"{where}: its nested model {plant.GetModelInstanceName(nested)!r} moves {count} "
                             f"degree{'s' * (count > 1)} of freedom; a model nested in the robot is fixed to it (its "
                             "joints of type fixed, one fixing it to the arm)")


def frame_by_name(plant: MultibodyPlant, name: str, instance=None):
    """The frame `name` of the robot: its own model's (in `instance`, or the plant's one frame of that name), or
    one of a model nested in it by its scoped name ("tip::tool0": frame tool0 of the nested model tip), either also
    written with the robot's own model name first ("arm::tool0", "arm::tip::tool0"); None where there is none."""
    if instance is not None:   # (the instance's name, or its last part: "ghost::arm" for a copy named with a prefix)
        own = plant.GetModelInstanceName(instance)
        for prefix in (own + "::", own.rsplit("::", 1)[-1] + "::"):
            if name.startswith(prefix):
                name = name.removeprefix(prefix)
                break
    if "::" not in name:
        if instance is None:
            return plant.GetFrameByName(name) if plant.HasFrameNamed(name) else None
        return plant.GetFrameByName(name, instance) if plant.HasFrameNamed(name, instance) else None
    scope, local = name.rsplit("::", 1)
    candidates = (map(ModelInstanceIndex, range(plant.num_model_instances())) if instance is None
                  else nested_instances(plant, instance))
    owners = [index for index in candidates if plant.GetModelInstanceName(index) == scope
              or plant.GetModelInstanceName(index).endswith("::" + scope)]
    found = [plant.GetFrameByName(local, owner) for owner in owners if plant.HasFrameNamed(local, owner)]
    return found[0] if len(found) == 1 else None


def nested_joint_note(plant: MultibodyPlant, name: str, instance) -> str:
    """What follows "joint NAME is not in FILE" where the joint moves a model nested in the robot's `instance` (Drake
    puts a joint in its child link's model): a robot's joints are its own model's; else nothing."""
    for nested in nested_instances(plant, instance):
        if plant.HasJointNamed(name, nested):
            return (f"'s own model but moves its nested model {plant.GetModelInstanceName(nested)!r}: a robot's joints "
                    "are its own model's (write the nested model into it, or include it with merge=\"true\")")
    return ""
