"""Data collection: kinematics and IK, trajectory planners, joint controllers and the sensor model,
the simulated robot, and the excitation and tracking protocols that write datasets.
Imports nothing from learning or deployment."""
