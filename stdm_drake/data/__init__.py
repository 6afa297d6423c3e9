"""Datasets: the file format, loading and checks, trajectory splits, transitions for learning, and
`stdm-drake inspect`."""
