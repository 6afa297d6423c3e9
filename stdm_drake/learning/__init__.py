"""Learning: the networks (models), training with the derivative loss (train), checkpoints,
NumPy inference and rollouts (predict), and test errors (evaluate)."""
