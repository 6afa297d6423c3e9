"""Deployment in Drake diagrams: the learned model as a LeafSystem, the trajectory optimizers (the real-time
iteration, iLQR) with their tagged settings, the MPC controller, its comparison and the MPC study
(`study.run_mpc_study`, the library's `stdm-drake mpc`)."""
