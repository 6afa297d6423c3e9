"""`stdm-drake export`'s job: a checkpoint as ONNX graphs (the model and its Jacobians) or as a Drake-native
model file, every check before any work, files written atomically."""
import dataclasses
import pathlib

from stdm_drake.errors import InputError
from stdm_drake.files import atomic_paths, line_text
from stdm_drake.outputs import check_output_file
from stdm_drake.deploy.drake_native import native_model, native_text

TARGETS = ("onnx", "drake")


@dataclasses.dataclass(frozen=True)
class ExportJob:
    """checkpoint: a `train` checkpoint (.pt); output: the file to write (.onnx for "onnx", .yaml for "drake");
    the ONNX target also writes the Jacobian graph beside it (`jacobian_path`); mean_only: its model graph without the
    variance and member outputs (`onnx_export.model_graph`)."""
    checkpoint: pathlib.Path
    output: pathlib.Path
    target: str = "onnx"
    mean_only: bool = False
    force: bool = False


def jacobian_path(output: pathlib.Path) -> pathlib.Path:
    """model.onnx -> model.jacobian.onnx (the Jacobian graph beside the model graph)."""
    output = pathlib.Path(output)
    return output.with_name(output.stem + ".jacobian" + (output.suffix or ".onnx"))


def export_job(job: ExportJob, say=print) -> list[pathlib.Path]:
    """Run the export; returns the files written. InputError (nothing written) for a checkpoint that is not one,
    an output that exists and stdm-drake's export did not write (without force), or a model the target cannot
    represent."""
    from stdm_drake.learning.checkpoint import load_checkpoint   # lazy: torch, pydrake, h5py
    if job.target not in TARGETS:
        raise InputError(f"--target must be one of {', '.join(TARGETS)}, got {job.target!r}")
    if job.mean_only and job.target != "onnx":
        raise InputError("--mean-only belongs to the onnx target (the Drake system gives the mean only)")
    suffix = ".onnx" if job.target == "onnx" else ".yaml"
    if pathlib.Path(job.output).suffix.lower() != suffix:
        raise InputError(f"-o/--output {job.output}: the {job.target} target writes a {suffix} file")
    given = pathlib.Path(job.output)
    for named in (given, given.resolve() if given.is_symlink() else given):   # (a link to a Jacobian graph too)
        if job.target == "onnx" and named.name.lower().endswith(".jacobian.onnx"):
            model_name = named.name[:-len(".jacobian.onnx")] + ".onnx"
            what = "is the name of" if named is given else f"links to {line_text(named.name)},"
            raise InputError(f"-o/--output {job.output} {what} a Jacobian graph: export writes the model graph to -o "
                             f"and its Jacobian graph beside it; give the model graph's name ({model_name})")
    outputs = [job.output] + ([jacobian_path(job.output)] if job.target == "onnx" else [])
    kind = "onnx" if job.target == "onnx" else "native"
    for option, path in zip(("-o/--output", "the Jacobian graph"), outputs):
        check_output_file(option, path, kind=kind, inputs=[job.checkpoint], force=job.force)
    checkpoint = load_checkpoint(job.checkpoint)
    network = checkpoint.model_config
    if job.mean_only and getattr(network, "ensemble_size", 0) == 1 and not getattr(network, "probabilistic", True):
        raise InputError(f"--mean-only: {job.checkpoint} is one deterministic network, whose graph gives the mean "
                         "alone already (no variance or member outputs to leave out); export it without the flag")
    if job.target == "onnx":
        from stdm_drake.deploy.onnx_export import checkpoint_graphs   # lazy: torch, onnx
        model, jacobian, features = checkpoint_graphs(checkpoint, mean_only=job.mean_only)
        contents = [model.SerializeToString(), jacobian.SerializeToString()]
    else:
        native = native_model(checkpoint)
        features = native.feature_input and f"input {native.feature_input!r} ({native.feature_width})"
        contents = [native_text(native).encode("utf-8")]
    with atomic_paths(outputs) as temporaries:      # the pair replaces what was there in one step, or not at all
        for temporary, content in zip(temporaries, contents):
            temporary.write_bytes(content)
    say(f"{line_text(checkpoint.path.name)} ({checkpoint.structure.label}, every {checkpoint.sample_period} s) -> "
        + " and ".join(line_text(path) for path in outputs))
    if features:
        say(f"note: the network sees physics features, so the exported model takes them as an input: {features}; "
            "the caller computes them at every step (see the file's metadata and docs/guides/deploy.md)")
    return outputs
