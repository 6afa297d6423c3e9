"""File helpers: atomic writes (temp file in the destination folder, then rename; a full disk as one line),
the free space a write needs (and the memory a run may use), the temporary files a killed run left, and JSON
of numpy values."""
import contextlib
import dataclasses
import errno
import glob
import math
import os
import pathlib
import re
import tempfile

from stdm_drake.errors import InputError
from stdm_drake.interrupts import protected, raise_if_received

# A write that fails for lack of room (full disk, quota, file size limit, read-only file system).
NO_ROOM = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS)
TEMP_SUFFIX = ".tmp"
# `atomic_path`'s temporary files: "." + the file's name + "." + mkstemp's 8 random characters + ".tmp"
TEMP_NAME = re.compile(r"^\..+\.[A-Za-z0-9_]{8}\.tmp$")


def size_text(size: float) -> str:
    """A size in bytes for a message: "0.615 MB", "2.81 GB"."""
    return f"{size / 1e9:.3g} GB" if size >= 1e9 else f"{size / 1e6:.3g} MB"


def nearest_existing(path, broken_links: bool = False) -> pathlib.Path:
    """`path` (made absolute), or the nearest folder above it that exists; with `broken_links`, a broken
    symbolic link on the way counts as existing (to name it in an error rather than look past it)."""
    path = pathlib.Path(path).absolute()
    for candidate in [path, *path.parents]:
        if candidate.exists() or (broken_links and candidate.is_symlink()):
            return candidate
    return pathlib.Path(path.anchor)


def free_bytes(folder) -> int:
    """Bytes this process may still write in `folder` (or the nearest folder above it that exists)."""
    stats = os.statvfs(nearest_existing(folder))
    return stats.f_bavail * stats.f_frsize


def available_memory() -> float | None:
    """Bytes of memory available to a new process here (Linux: MemAvailable; None where unknown)."""
    try:
        with open("/proc/meminfo", encoding="ascii") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return float(line.split()[1]) * 1024
    except OSError:
        pass
    return None


def file_size_limit() -> float:
    """The largest file this process may write, bytes (`ulimit -f`; inf when unlimited)."""
    import resource
    soft, _ = resource.getrlimit(resource.RLIMIT_FSIZE)
    return math.inf if soft == resource.RLIM_INFINITY else float(soft)


def check_free_space(path, needed: int, grown_size: int | None = None) -> None:
    """InputError (one line naming `path` and the space it needs) unless `needed` more bytes fit beside `path`
    and (given `grown_size`: the file's size after the write, bytes) the file stays within the file size limit
    (past either, HDF5 crashes)."""
    path = pathlib.Path(path)
    free = free_bytes(path.parent)
    if needed > free:
        raise InputError(f"not enough space to write {path}: it needs about {size_text(needed)}, "
                         f"{size_text(free)} free there")
    if grown_size is not None and grown_size > file_size_limit():
        raise InputError(f"cannot write {path}: it would grow to about {size_text(grown_size)}, beyond the file "
                         f"size limit of {size_text(file_size_limit())} (ulimit -f)")


# An output is refused at once where less than this is free: a command would fail on its first write (and
# leave a half-filled folder) on a disk that full.
MIN_FREE_BYTES = 1 << 20


def check_room(option: str, path: pathlib.Path, folder: pathlib.Path) -> None:
    """InputError unless MIN_FREE_BYTES are free in `folder` (or the nearest folder above it), where the output
    `path` (given as `option`) goes."""
    free = free_bytes(folder)
    if free < MIN_FREE_BYTES:
        raise InputError(f"{option} {path}: only {size_text(free)} free there; stdm-drake needs at least "
                         f"{size_text(MIN_FREE_BYTES)} free to write an output")


def no_room_error(path, error: OSError) -> InputError:
    """The one line for a write to `path` that failed for lack of room (`NO_ROOM`): with the free space, the
    file size limit, or the file system's lack of inodes, whichever it was."""
    folder = pathlib.Path(path).absolute().parent
    if error.errno == errno.EFBIG:
        room = f"the file size limit is {size_text(file_size_limit())}, ulimit -f"
    elif error.errno == errno.ENOSPC and os.statvfs(nearest_existing(folder)).f_favail == 0:
        room = "no inode left there: too many files"
    else:
        room = f"{size_text(free_bytes(folder))} free there"
    return InputError(f"cannot write {path}: {error.strerror or os.strerror(error.errno)} ({room}); nothing was "
                      "replaced")


def path_text(path) -> str:
    """`path` (or a name) as text every UTF-8 writer takes (ONNX, YAML, HDF5): the bytes of a name that is not
    UTF-8 (Python holds them as surrogates) as \\xNN escapes, as `ls -b` shows them; other names unchanged."""
    return os.fsencode(str(path)).decode("utf-8", errors="backslashreplace")


def printable_text(text: str, keep: str = "") -> str:
    """`text` with every character that is not printable (a line break, a carriage return, a terminal escape,
    U+2028), other than those in `keep`, as its Python escape ("\\n", "\\x1b")."""
    return "".join(character if character.isprintable() or character in keep else repr(character)[1:-1]
                   for character in text)


def line_text(text) -> str:
    """`text` (a name, a path) on one line as every reader takes it: `path_text`, and every character that is not
    printable (a line break, U+2028, other controls) as its Python escape ("\\n"), so that it cannot end a
    comment, a header or a printed line."""
    return printable_text(path_text(text))


def names_text(names, shown: int = 8) -> str:
    """Names for one line: the first `shown`, each `line_text`, then how many more ("a, b, c and 49,997 more"): a
    message listing 50,000 names was one line of 389,147 characters."""
    names = [line_text(name) for name in names]
    more = len(names) - shown
    return ", ".join(names[:shown]) + (f" and {more:,} more" if more > 0 else "")


@contextlib.contextmanager
def atomic_path(path):
    """Yield a temporary path beside `path`; on success rename it to `path`, on error delete it (`atomic_paths`
    of one file).

    Readers never see a half-written file, and a failed write leaves no file behind; a write that runs out
    of room (`NO_ROOM`) is an InputError naming `path`.
    """
    with atomic_paths([path]) as (temp,):
        yield temp


@contextlib.contextmanager
def atomic_paths(paths):
    """Yield a temporary path beside each of `paths` (a list); when the block succeeds, rename them all in one step
    that no signal cuts (one arriving then is raised once every file is in place: files written as a set, such as
    export's model and Jacobian graphs, are never torn apart); on error delete them, replacing nothing.

    A command that a signal interrupted replaces nothing, even where a library swallowed the signal
    (`interrupts.raise_if_received`); a write that runs out of room (`NO_ROOM`) is an InputError naming the file.
    """
    paths = [pathlib.Path(path) for path in paths]
    umask = os.umask(0)
    os.umask(umask)
    temps: list[str] = []
    current = paths[0]
    try:
        for current in paths:
            current.parent.mkdir(parents=True, exist_ok=True)
            with protected():   # (a signal as the file appears is raised once its name is known: the finally removes it)
                handle, name = tempfile.mkstemp(prefix=f".{current.name}.", suffix=TEMP_SUFFIX, dir=current.parent)
                os.close(handle)
                temps.append(name)
        current = paths[0]
        yield [pathlib.Path(name) for name in temps]
        raise_if_received()
        with protected():
            for name, current in zip(temps, paths):
                os.chmod(name, 0o666 & ~umask)  # mkstemp creates 0600; give the usual permissions
                os.replace(name, current)
    except OSError as error:   # (mkstemp without an inode left: a full disk too)
        if error.errno in NO_ROOM:
            raise no_room_error(current, error) from None
        raise
    finally:
        with protected():
            for name in temps:
                if os.path.exists(name):
                    os.unlink(name)


def remove_stale_temporaries(folder, name: str | None = None, recursive: bool = False) -> list[pathlib.Path]:
    """Delete the temporary files a killed run left in `folder` (those of the file `name` only, or all of
    them; `recursive`: in its subfolders too). Call it only while holding the output's lock (no live run
    writes there). Returns what it removed."""
    folder = pathlib.Path(folder)
    if not folder.is_dir():
        return []
    pattern = f".{glob.escape(name)}.*{TEMP_SUFFIX}" if name else f".*{TEMP_SUFFIX}"
    removed = []
    for candidate in (folder.rglob(pattern) if recursive else folder.glob(pattern)):
        if TEMP_NAME.match(candidate.name) and candidate.is_file() and not candidate.is_symlink():
            with contextlib.suppress(FileNotFoundError):
                candidate.unlink()
                removed.append(candidate)
    return removed


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


def finite_json(value):
    """`value` (dicts, lists, numbers, numpy) with every non-finite float as None, for strict JSON (json.dumps
    would write Infinity / NaN, which JSON does not have): an infinite error (a diverged rollout) is null; file
    names as `escaped_names` writes them."""
    import math
    import numpy as np
    if isinstance(value, dict):
        return {key: finite_json(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite_json(item) for item in value]
    if isinstance(value, np.ndarray):
        return finite_json(value.tolist())
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return escaped_names(value)


def escaped_names(value):
    """`value` (dicts, lists, anything) with every string that holds a file name's non-UTF-8 bytes (surrogates,
    which json.dumps writes as "\\udcff" and strict JSON parsers reject) as `path_text` shows them ("\\xff")."""
    if isinstance(value, dict):
        return {escaped_names(key): escaped_names(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [escaped_names(item) for item in value]
    if isinstance(value, pathlib.PurePath):
        value = str(value)
    if isinstance(value, str) and any("\udc80" <= character <= "\udcff" for character in value):
        return path_text(value)
    return value


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
