"""Where the robot descriptions (models/), plan specifications (trajectories/) and controller settings
(controllers/) are: inside the installed package (stdm_drake/_data, put there by a wheel build, see
pyproject.toml) or, in a source checkout or an editable install, the repository root."""
import pathlib


def _data_root() -> pathlib.Path:
    """The folder holding models/, trajectories/ and controllers/ (see the module docstring)."""
    package = pathlib.Path(__file__).resolve().parent
    installed = package / "_data"
    return installed if (installed / "models").is_dir() else package.parent


DATA_ROOT = _data_root()
MODELS_DIR = DATA_ROOT / "models"
TRAJECTORIES_DIR = DATA_ROOT / "trajectories"
CONTROLLERS_DIR = DATA_ROOT / "controllers"
