"""Makes the scripts in tools/ and the studies in tools/studies/ importable from tests (tools/ is not a package)."""
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
generate_panda_urdf = _load("generate_panda_urdf")
results_provenance = _load("results_provenance")
study = _load("study")   # the studies' launcher, tools/study.py: study.main(["NAME", ...]) runs one
# the study modules of tools/studies/, imported as `studies.<name>` (the launcher puts tools/ on the path, so
# their pools' spawned workers import them too)
jacobian_accuracy = study.load("jacobian-accuracy")
decisive = study.load("decisive")
closed_loop = study.load("closed-loop")
reality_gap = study.load("reality-gap")
identification = study.load("identification")
identification_closed_loop = study.load("identification_closed_loop")   # (a part of it, not a study)
import_round_trip = study.load("import-round-trip")
default_train = study.load("default-train")
sample_efficiency = study.load("sample-efficiency")
settling = study.load("settling")
reality_gap_plans = study.load("reality-gap-plans")
robot_corpus = study.load("robot-corpus")
