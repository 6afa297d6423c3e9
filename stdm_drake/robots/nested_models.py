"""The robot's model instances in a plant: the one its file adds and the models nested in it (an SDF model's inner
or <include>d models, "arm::tool", a tool welded to the arm). Used by `robots.robot` (loading and checking the
robot) and `robots.plant` (its collision filters)."""
from pydrake.multibody.plant import MultibodyPlant

from stdm_drake.errors import InputError


def robot_instance(plant: MultibodyPlant, instances, where: str):
    """The robot's model instance among the `instances` Drake's parser added for its one file: the first, the others
    nested in it (an SDF model's <include>d or inner models, "arm::tool": part of the robot, their joints fixed:
    `check_nested_fixed`). InputError (one line, `where`: the robot and file) for a file of several models side by
    side, or of none."""
    names = [plant.GetModelInstanceName(instance) for instance in instances]
    if not names or any(not name.startswith(names[0] + "::") for name in names[1:]):
        raise InputError(f"{where} holds {len(names)} models ({', '.join(names[:5])}), expected one (with the models "
                         "nested in it)")
    return instances[0]


def nested_instances(plant: MultibodyPlant, instance) -> list:
    """The model instances nested in the robot's `instance` (an SDF's inner or <include>d models: "arm::tool")."""
    prefix = plant.GetModelInstanceName(instance) + "::"
    return [index for index in map(type(instance), range(plant.num_model_instances()))
            if plant.GetModelInstanceName(index).startswith(prefix)]


def check_nested_fixed(plant: MultibodyPlant, instance, where: str) -> None:
    """After Finalize: InputError where a model nested in the robot's `instance` moves (a joint of its own, or no
    joint to the arm at all): the robot's state is its own joints'."""
    for nested in nested_instances(plant, instance):
        if plant.num_velocities(nested):
            count = plant.num_velocities(nested)
            raise InputError(f"{where}: its nested model {plant.GetModelInstanceName(nested)!r} moves {count} "
                             f"degree{'s' * (count > 1)} of freedom; a model nested in the robot is fixed to it (its "
                             "joints of type fixed, one fixing it to the arm)")
