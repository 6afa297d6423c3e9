"""Same seeds give the same data and the same weights as before the package was restructured.

The reference values were computed with the code of commit 799fd2b (one module per stage, before
the subpackages) on the session fixtures' datasets and a 3-epoch PED run; the restructured code
gave identical values (weights bitwise). The datasets are compared exactly (every array, and every
collection-metadata key that existed then, package versions aside); the weights by the sum of |w| per tensor to 1e-6
relative, so that a CPU with other vector instructions may round differently without failing,
while any change of seed, split, data or architecture would move them by far more.
"""
import hashlib
import json

import h5py
import numpy as np
import pytest
import torch

from stdm_drake.cli import main

# sha256 over every array (by name), and over the collection metadata's keys as they were (package
# versions aside; keys added since, like the robot's name or the controller's empty sizing fields, are not
# part of the comparison)
DATASET_ARRAYS_SHA256 = {
    "excitation": "05234ff90ac845c1bc50dd359874648dba5914500116e3c16f8a042b426fee32",
    "tracking": "c71777eb1c72ec4fdb565ae61135254759be06b9f0ab1eff6805383a410e2570",
}
DATASET_METADATA_SHA256 = {
    "excitation": "5c5be040ce0950ad405a312a39404e7fac1f7157686c81ac758ba933f02fef10",
    "tracking": "77379737874ac8b889c8d1b013798768049462f5c6d888aed23c951bc4a6c0bb",
}
METADATA_KEYS = {
    "excitation": ["excitation", "excitation_parameters", "excitation_parameters_columns", "joint_names",
                   "num_trajectories", "plant", "protocol", "robot_model_sha256", "sample_period", "seed", "sensor",
                   "torque_hold"],
    "tracking": ["controller", "joint_names", "num_trajectories", "planner", "plant", "protocol",
                 "robot_model_sha256", "sample_period", "seed", "sensor", "task_space_sampling", "torque_hold"],
}
PED_WEIGHT_ABS_SUMS = {  # `train tracking.h5 --model PED --ensemble-size 2 --epochs 3 --train 1 --val 1`
    "biases.0": 2.0941610610461794, "biases.1": 1.807498714828398, "biases.2": 1.7212671341840178,
    "biases.3": 0.46276067825965583, "input_normalizer.mean": 97.08296090655577,
    "input_normalizer.std": 27.532644520513713, "max_logvar": 12.046423316001892, "min_logvar": 239.4958906173706,
    "output_normalizer.mean": 0.005100442062030197, "output_normalizer.std": 0.07142730482155457,
    "weights.0": 409.8495265604506, "weights.1": 1753.893147531904, "weights.2": 1753.4748684044098,
    "weights.3": 534.5573389155616,
}


def dataset_hashes(path, keys) -> tuple[str, str]:
    """(sha256 of every array by name, sha256 of the metadata restricted to `keys`)."""
    arrays = hashlib.sha256()
    with h5py.File(path, "r") as f:
        def visit(name, item):
            if isinstance(item, h5py.Dataset):
                arrays.update(name.encode())
                arrays.update(np.ascontiguousarray(item[()]).tobytes())
        f.visititems(visit)
        metadata = json.loads(f.attrs["metadata_json"])
    kept = {key: metadata[key] for key in keys}
    if "controller" in kept:  # fields added since (PID sizing), empty in files of gains given by hand
        kept["controller"] = {key: value for key, value in kept["controller"].items()
                              if not (key in ("bandwidth", "dither_acceleration") and value == [])}
    return arrays.hexdigest(), hashlib.sha256(json.dumps(kept, sort_keys=True).encode()).hexdigest()


@pytest.mark.parametrize("protocol", sorted(DATASET_ARRAYS_SHA256))
def test_same_seed_same_dataset_as_before(protocol, request):
    path = request.getfixturevalue(f"{protocol}_dataset")
    assert dataset_hashes(path, METADATA_KEYS[protocol]) == (DATASET_ARRAYS_SHA256[protocol],
                                                             DATASET_METADATA_SHA256[protocol])


def test_same_seed_same_weights_as_before(tracking_dataset, tmp_path):
    assert main(["train", str(tracking_dataset), "--predicts", "state", "--inputs", "raw", "--model", "PED", "--ensemble-size", "2", "--epochs", "3",
                 "--train", "1", "--val", "1", "--quiet", "-o", str(tmp_path)]) == 0
    weights = torch.load(tmp_path / "seed0" / "checkpoint.pt", weights_only=True)["weights"]
    sums = {name: float(value.double().abs().sum()) for name, value in weights.items()}
    assert sums.keys() == PED_WEIGHT_ABS_SUMS.keys()
    for name, expected in PED_WEIGHT_ABS_SUMS.items():
        assert sums[name] == pytest.approx(expected, rel=1e-6), name
