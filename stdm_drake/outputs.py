"""The one rule for everything a command writes, checked before any work starts:

- an output is never one of the command's inputs (the same file, whatever the path or link says);
- a file output is a regular file or nothing yet, a folder output a folder or nothing yet, and the
  folder it goes in can be written;
- what exists there already is replaced only if stdm-drake wrote it (a dataset file, a JSON or HTML
  file it marked, a folder it marked or that holds the command's own results), or with --force.

Every violation is an InputError of one line, so the command exits with status 2 having done nothing.
"""
import json
import os
import pathlib
import stat

from stdm_drake.errors import InputError

# Written into every output folder a command fills, and looked for before replacing one.
FOLDER_MARKER = ".stdm-drake-output"
# The first line of every HTML file stdm-drake writes, and the key of every JSON file.
HTML_MARKER = "<!-- written by stdm-drake -->"
IDENTIFIED_MARKER = "# An identified robot, written by `stdm-drake identify`"   # first line of identified.yaml
JSON_MARKER = "written_by"
DATASET_FORMAT = "stdm-drake-dataset"  # the HDF5 "format" attribute of every dataset (stdm_drake.data.dataset)


def _same_file(a: pathlib.Path, b: pathlib.Path) -> bool:
    try:
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:
        return False


def _nearest_existing(path: pathlib.Path) -> pathlib.Path:
    for parent in [path, *path.parents]:
        if parent.exists() or parent.is_symlink():
            return parent
    return pathlib.Path(".")


def _check_parent(option: str, path: pathlib.Path) -> None:
    """The folder `path` goes in is a folder (or can be made one) that can be written."""
    existing = _nearest_existing(path.absolute().parent)
    if not existing.is_dir():
        raise InputError(f"{option} {path}: {existing} is not a folder")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise InputError(f"{option} {path}: cannot write in {existing} (permission denied)")


def _check_not_input(option: str, path: pathlib.Path, inputs) -> None:
    for source in inputs:
        if source is None:
            continue
        source = pathlib.Path(source)
        if _same_file(path, source) or path.absolute() == source.absolute():
            raise InputError(f"{option} {path} is one of the command's inputs ({source}); choose another path")


def _written_by_us(path: pathlib.Path, kind: str) -> bool:
    """Whether the regular file at `path` is a stdm-drake output of `kind` ("dataset", "json", "identified",
    "html")."""
    try:
        if kind == "dataset":
            import h5py
            with h5py.File(path, "r") as f:
                return f.attrs.get("format") == DATASET_FORMAT
        if kind == "json":
            with open(path, encoding="utf-8") as f:
                data = json.load(f)
            return isinstance(data, dict) and str(data.get(JSON_MARKER, "")).startswith("stdm-drake")
        if kind == "identified":
            with open(path, encoding="utf-8", errors="replace") as f:
                return f.readline().startswith(IDENTIFIED_MARKER)
        if kind == "html":
            with open(path, encoding="utf-8", errors="replace") as f:
                return f.readline().strip() == HTML_MARKER
    except (OSError, ValueError):
        return False
    raise ValueError(f"unknown output kind {kind!r}")


def check_output_file(option: str, path, *, kind: str, inputs=(), force: bool = False) -> pathlib.Path | None:
    """Check a file the command will write (option: its flag, for messages; kind: "dataset", "json",
    "identified" or "html"; inputs: the files the command reads). Returns the path (None stays None)."""
    if path is None:
        return None
    path = pathlib.Path(path)
    _check_not_input(option, path, inputs)
    if path.exists() or path.is_symlink():
        mode = os.stat(path).st_mode if path.exists() else 0
        if path.is_dir():
            raise InputError(f"{option} {path} is a folder; give a file path")
        if not stat.S_ISREG(mode):
            raise InputError(f"{option} {path} is not a regular file (a device, pipe or broken link); "
                             "give a file path")
        if not force and not _written_by_us(path, kind):
            raise InputError(f"{option} {path} exists and stdm-drake did not write it; pass --force to replace it")
        if not os.access(path, os.W_OK) and not os.access(path.parent, os.W_OK):
            raise InputError(f"{option} {path}: cannot replace it (permission denied)")
    _check_parent(option, path)
    return path


def check_output_folder(option: str, path, *, inputs=(), own_files=(), force: bool = False) -> pathlib.Path:
    """Check a folder the command will fill: missing, empty, marked by stdm-drake, holding one of the
    command's own result files (`own_files`, names relative to it, from runs before the marker), or
    --force. A folder that is one of the inputs, or an existing file, is refused."""
    path = pathlib.Path(path)
    _check_not_input(option, path, inputs)
    if path.exists() or path.is_symlink():
        if not path.is_dir():
            raise InputError(f"{option} {path} exists and is not a folder; give a folder path")
        ours = (path / FOLDER_MARKER).exists() or any((path / name).exists() for name in own_files)
        if not force and not ours and any(path.iterdir()):
            raise InputError(f"{option} {path} is a folder stdm-drake did not write (not empty); choose another "
                             "or pass --force to write into it")
        if not os.access(path, os.W_OK | os.X_OK):
            raise InputError(f"{option} {path}: cannot write in it (permission denied)")
    else:
        _check_parent(option, path / "x")
    return path


def mark_output_folder(path) -> None:
    """Create the output folder if needed and mark it as stdm-drake's."""
    path = pathlib.Path(path)
    path.mkdir(parents=True, exist_ok=True)
    marker = path / FOLDER_MARKER
    if not marker.exists():
        marker.write_text("This folder holds stdm-drake outputs; stdm-drake may replace what is in it.\n")


def add_force_argument(parser) -> None:
    parser.add_argument("--force", action="store_true",
                        help="replace an existing output that stdm-drake did not write")
