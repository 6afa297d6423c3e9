"""Datasets: the file format, loading and checks, trajectory splits, transitions for learning, their
summaries, and which robot a dataset belongs to."""
