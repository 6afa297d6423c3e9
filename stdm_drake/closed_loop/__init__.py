"""Deployment in Drake diagrams: the learned model as a LeafSystem, the plant model with AutoDiff
linearization, the iLQR solver, the MPC controller and its comparison, and the Meshcat viewer."""
