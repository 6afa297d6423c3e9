"""Deployment in Drake diagrams: the learned model as a LeafSystem, the trajectory optimizers (the real-time
iteration, iLQR), the MPC controller and its comparison."""
