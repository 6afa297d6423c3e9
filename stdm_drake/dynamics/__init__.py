"""Dynamics: the one model contract (`model.DynamicsModel`), the models that need no learning (the
physics baselines and the robot's plant as a model: `physics`), a plant model's step as a grey box's
physics part (`plant_step`), and the way from a model file to a model (`model_files.load_model`).
It sits below learning, identification and closed_loop and imports none of them: the model-file registry
names the loaders of their files by "module:function" strings, imported when a file of that kind is read (as
the command line names its commands)."""
