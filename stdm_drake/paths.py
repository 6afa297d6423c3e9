"""Where the robot descriptions (models/), plan specifications (trajectories/) and controller settings
(controllers/) are: inside the installed package (stdm_drake/_data, put there by a wheel build, see
pyproject.toml) or, in a source checkout or an editable install, the repository root. A path written
`stdm-drake:controllers/pid.yaml` names such a shipped file from any folder, installed or not. Also the one
check of a file a command reads (`check_input_file`)."""
import errno
import pathlib
import stat
from stdm_drake.errors import InputError

SHIPPED_PREFIX = "stdm-drake:"


def _data_root() -> pathlib.Path:
    """The folder holding models/, trajectories/ and controllers/ (see the module docstring)."""
    package = pathlib.Path(__file__).resolve().parent
    installed = package / "_data"
    return installed if (installed / "models").is_dir() else package.parent


DATA_ROOT = _data_root()
MODELS_DIR = DATA_ROOT / "models"
TRAJECTORIES_DIR = DATA_ROOT / "trajectories"
CONTROLLERS_DIR = DATA_ROOT / "controllers"


def shipped_file(text: str) -> pathlib.Path:
    """The file `text` = "stdm-drake:FOLDER/NAME" names among the shipped models/, trajectories/ and
    controllers/. ValueError, listing that folder's files, for anything else."""
    relative = pathlib.PurePosixPath(text[len(SHIPPED_PREFIX):])
    folder = relative.parts[0] if relative.parts else ""
    if folder not in ("models", "trajectories", "controllers") or len(relative.parts) != 2:
        raise ValueError(f"{text}: a shipped file is stdm-drake:models/NAME, stdm-drake:trajectories/NAME or "
                         "stdm-drake:controllers/NAME")
    path = DATA_ROOT / folder / relative.name
    if not path.is_file():
        names = sorted(item.name for item in (DATA_ROOT / folder).iterdir() if item.suffix in (".yaml", ".urdf", ".sdf"))
        raise ValueError(f"{text}: no such shipped file; {folder}/ holds {', '.join(names)}")
    return path


def expand_shipped(argument: str) -> str:
    """A command-line argument with a leading "stdm-drake:" (or "--option=stdm-drake:") made the shipped
    file's path (see `shipped_file`); any other argument unchanged."""
    option, separator, value = argument.partition("=")
    if argument.startswith(SHIPPED_PREFIX):
        return str(shipped_file(argument))
    if separator and option.startswith("--") and value.startswith(SHIPPED_PREFIX):
        return f"{option}={shipped_file(value)}"
    return argument


def shipped_hint(path) -> str:
    """For a missing relative path FOLDER/NAME whose NAME is a shipped file of models/, trajectories/ or
    controllers/ (a path copied from a recipe, run outside the checkout): "; the shipped one is
    stdm-drake:FOLDER/NAME"; else ""."""
    parts = pathlib.PurePath(path).parts
    if len(parts) == 2 and parts[0] in ("models", "trajectories", "controllers") and (DATA_ROOT / parts[0] / parts[1]).is_file():
        return f" (the shipped one is {SHIPPED_PREFIX}{parts[0]}/{parts[1]})"
    return ""


def check_input_file(path, what: str, missing=None) -> pathlib.Path:
    """`path` as a Path when it names a regular file to read (a symlink to one included); otherwise an
    error naming `what` ("dataset", "robot ur10: model file", ...) and what the path is instead: a
    folder, not a regular file (a FIFO, socket or device, which reading would block on or consume),
    a symlink loop, or not there. missing: the exception type for a path that is not there (default
    InputError; FileNotFoundError where callers catch that); the others are InputError."""
    path = pathlib.Path(path)
    try:
        mode = path.stat().st_mode
    except OSError as error:
        if error.errno == errno.ELOOP:
            raise InputError(f"{what} {path} is a symlink loop (its links point at each other)") from None
        if error.errno in (errno.ENOENT, errno.ENOTDIR):
            raise (missing or InputError)(f"{what} not found: {path}{shipped_hint(path)}") from None
        raise InputError(f"{what} {path} cannot be read ({error.strerror})") from None
    if stat.S_ISDIR(mode):
        raise InputError(f"{what} {path} is a folder, not a file")
    if not stat.S_ISREG(mode):
        raise InputError(f"{what} {path} is not a regular file (a FIFO, socket or device)")
    return path
