"""Learning: the networks (models), the training problem (problem), training with the derivative loss (trainer), checkpoints,
NumPy inference and rollouts (predict), and test errors (evaluate)."""
