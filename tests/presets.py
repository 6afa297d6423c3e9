"""Robots the tests use by name: the library takes the robot as an argument everywhere below the
commands, so tests load the shipped presets here once per process."""
from stdm_drake.robots.robot import UR10_CONFIG, load_robot

UR10 = load_robot(UR10_CONFIG)
