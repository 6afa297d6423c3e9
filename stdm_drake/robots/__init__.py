"""Robots, at the bottom of the package: the typed robot config and the Robot it loads, what
stdm-drake reads in a model file itself, plants and their dynamics, limits and self-collision
checks, kinematics and IK, the joint sensor and tracking controllers, the simulated station the
data protocols step, and the Meshcat recorder. Imports no stage."""
