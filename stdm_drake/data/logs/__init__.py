"""A real robot's logs as datasets (`stdm-drake import`, docs/real_logs.md): readers of UR RTDE CSV files and
ROS 2 bags (`rtde`, `ros2`) stream rows into `importer`, which splits them into trajectories, resamples them
onto the sample period (`resample`) and writes a dataset of protocol "logged"; `mapping` is the typed file of
what a log does not say; `simulated` writes the project's simulated datasets in those formats (the tests'
and the benchmark's logs)."""
