"""Data collection: task-space plans and their planners, and the excitation and tracking protocols
that step a robot's station (`stdm_drake.robots.station`) and write datasets.
Imports nothing from learning or deployment."""
