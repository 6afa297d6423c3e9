"""Makes the scripts in tools/ importable from tests (tools/ is not a package)."""
import importlib.util
import pathlib
import sys

TOOLS = pathlib.Path(__file__).resolve().parents[1] / "tools"


def _load(name):
    spec = importlib.util.spec_from_file_location(name, TOOLS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


generate_ur10_urdf = _load("generate_ur10_urdf")
benchmark_report = _load("benchmark_report")
jacobian_accuracy = _load("jacobian_accuracy")
generate_panda_urdf = _load("generate_panda_urdf")
decisive_experiment = _load("decisive_experiment")
closed_loop_study = _load("closed_loop_study")
reality_gap = _load("reality_gap")
identification_study = _load("identification_study")
import_round_trip = _load("import_round_trip")
default_train_study = _load("default_train_study")
