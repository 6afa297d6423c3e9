"""Same seeds give the same data and the same weights as before the package was restructured.

The reference values were computed with the code of commit 799fd2b (one module per stage, before
the subpackages) on the session fixtures' datasets and a 3-epoch PED run; the restructured code
gave identical values (weights bitwise). The collection metadata (every key that existed then,
package versions aside, as the code records them now: see DATASET_METADATA_SHA256) is compared
exactly; the arrays by the sum of |value| per array name to 1e-9
relative and the weights by the sum of |w| per tensor to 1e-6 relative, so that a CPU with other
vector instructions may round differently without failing (Drake's simulation gives bitwise other
arrays on an AMD EPYC than on the Intel Xeon the exact hashes were taken on: the array sums below were
taken on the EPYC with the unchanged collection code of commit 072272d), while any change of seed,
sampling, controller or plant moves them by far more.
"""
import hashlib
import json

import h5py
import numpy as np
import pytest
import torch

from stdm_drake.cli import main

# sum of |value| over every trajectory's array of each name; sha256 over the collection metadata's keys as
# they were (package versions aside; keys added since, like the robot's name, are not part of the comparison)
DATASET_ARRAY_ABS_SUMS = {
    "excitation": {"q": 1818.477159353079, "q_true": 1818.477159353079, "qdd": 2345.0447985361334,
                   "qdd_end": 2294.476041213148, "tau": 21075.313964412486, "tau_next": 422.8088496972069,
                   "v": 512.5155686194921, "v_true": 512.5155686194921},
    "tracking": {"q": 5799.350139095533, "q_planned": 5799.20616992823, "q_true": 5799.339343423303,
                 "qdd": 2348.8415506493807, "qdd_end": 2349.3998641027815, "qdd_planned": 2283.9538790680117,
                 "tau": 73231.2510809768, "tau_next": 766.2329628684851, "v": 603.080269181547,
                 "v_planned": 601.2353692853186, "v_true": 600.5534032933464},
}
# the metadata as the current code records it. Against commit 799fd2b's (whose sha256 were 5c5be040... and
# 77379737...) it differs only in its layout, checked field by field by collecting with both: the plant
# records every field of Drake's MultibodyPlantConfig (the values 799fd2b's plant had as Drake's defaults);
# the quintic planner no longer records the ruckig/toppra fields (jerk_limits, path_waypoints,
# toppra_gridpoints, toppra_limit_margin) nor the inverse-dynamics controller the PID's gravity_feedforward
# and empty bandwidth, fields those kinds never read. The array sums above are unchanged. Since issue 42 the
# inverse-dynamics controller records damping_compensation ("planned"; the UR-10 has no joint damping, so the
# data are the same): without that field the tracking metadata's sha256 is the former 42542d26...
DATASET_METADATA_SHA256 = {
    "excitation": "93ab19036d481c5510769b385b31432f3c019d5ec0afbb0d621cca1267bcd371",
    "tracking": "80f1e7959782bf8636f23b5f1ca7d8654d5aecc85f659073a6ce3a3c508ca638",
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


def dataset_summary(path, keys) -> tuple[dict, str]:
    """(sum of |value| per array name over all trajectories, sha256 of the metadata restricted to `keys`)."""
    sums = {}
    with h5py.File(path, "r") as f:
        def visit(name, item):
            if isinstance(item, h5py.Dataset):
                key = name.split("/")[-1]
                sums[key] = sums.get(key, 0.0) + float(np.abs(np.asarray(item[()], dtype=float)).sum())
        f.visititems(visit)
        metadata = json.loads(f.attrs["metadata_json"])
    kept = {key: metadata[key] for key in keys}
    return sums, hashlib.sha256(json.dumps(kept, sort_keys=True).encode()).hexdigest()


@pytest.mark.parametrize("protocol", sorted(DATASET_ARRAY_ABS_SUMS))
def test_same_seed_same_dataset_as_before(protocol, request):
    path = request.getfixturevalue(f"{protocol}_dataset")
    sums, metadata = dataset_summary(path, METADATA_KEYS[protocol])
    assert metadata == DATASET_METADATA_SHA256[protocol]
    assert sums.keys() == DATASET_ARRAY_ABS_SUMS[protocol].keys()
    for name, expected in DATASET_ARRAY_ABS_SUMS[protocol].items():
        assert sums[name] == pytest.approx(expected, rel=1e-9), name


def test_same_seed_same_weights_as_before(tracking_dataset, tmp_path):
    assert main(["train", str(tracking_dataset), "--predicts", "state", "--inputs", "raw", "--model", "PED", "--ensemble-size", "2", "--epochs", "3",
                 "--alpha", "1e-3", "--derivative-source", "planned",   # (train's defaults before they were chosen)
                 "--train", "1", "--val", "1", "--quiet", "-o", str(tmp_path)]) == 0
    weights = torch.load(tmp_path / "seed0" / "checkpoint.pt", weights_only=True)["weights"]
    sums = {name: float(value.double().abs().sum()) for name, value in weights.items()}
    assert sums.keys() == PED_WEIGHT_ABS_SUMS.keys()
    for name, expected in PED_WEIGHT_ABS_SUMS.items():
        assert sums[name] == pytest.approx(expected, rel=1e-6), name
