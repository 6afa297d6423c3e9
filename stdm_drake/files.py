"""Atomic file writes: write a temp file in the destination folder, then rename over the target."""
import contextlib
import os
import pathlib
import tempfile


@contextlib.contextmanager
def atomic_path(path):
    """Yield a temporary path beside `path`; on success rename it to `path`, on error delete it.

    Readers never see a half-written file, and a failed write leaves no file behind.
    """
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, temp_name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(handle)
    umask = os.umask(0)
    os.umask(umask)
    try:
        yield pathlib.Path(temp_name)
        os.chmod(temp_name, 0o666 & ~umask)  # mkstemp creates 0600; give the usual permissions
        os.replace(temp_name, path)
    finally:
        if os.path.exists(temp_name):
            os.unlink(temp_name)


def write_text_atomic(path, text: str) -> pathlib.Path:
    with atomic_path(path) as temp:
        temp.write_text(text)
    return pathlib.Path(path)
