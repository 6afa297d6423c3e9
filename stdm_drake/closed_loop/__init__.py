"""Deployment in Drake diagrams: the learned model as a LeafSystem, the plant model with AutoDiff
linearization, the trajectory optimizers (iLQR), the MPC controller and its comparison."""
