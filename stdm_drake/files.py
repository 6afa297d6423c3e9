"""File helpers: atomic writes (temp file in the destination folder, then rename) and JSON of numpy values."""
import contextlib
import dataclasses
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


def json_default(value):
    """`default=` for json.dumps: numpy arrays and scalars, paths and dataclasses as plain JSON."""
    import numpy as np
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, pathlib.PurePath):
        return str(value)
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return dataclasses.asdict(value)
    raise TypeError(f"not JSON-serializable: {type(value).__name__}")


def rows_csv(rows: list[dict], columns: list[str] | None = None) -> str:
    """CSV text of result rows (columns: default the first row's keys); floats with 6 significant digits,
    fields quoted only where they hold a comma or quote."""
    import csv
    import io
    columns = list(rows[0]) if columns is None else columns
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(columns)
    for row in rows:
        writer.writerow([f"{row[c]:.6g}" if isinstance(row[c], float) else row[c] for c in columns])
    return buffer.getvalue()
