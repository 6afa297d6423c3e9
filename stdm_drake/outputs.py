"""The one rule for everything a command writes, checked before any work starts (a violation is an InputError
of one line, so the command exits with status 2 having done nothing):

- an output is never one of the command's inputs (the same file, whatever the path or link says);
- a file output is a regular file or nothing yet, a folder output a folder or nothing yet, and the
  folder it goes in can be written;
- what exists there already is replaced only with --force, or if the same command wrote it (a JSON or HTML file
  it marked, a folder it marked or holding its results) and it is no dataset or identified robot (PRODUCT_KINDS:
  others are made from them and record them); every output records the command that wrote it;
- one run at a time per output: while a command runs (`command_outputs`) each output it checks is locked
  (a lock file beside it, `fcntl.flock`, released by the kernel if the run dies); a second run's error
  names the first's process. Holding the lock, the temporary files a killed run left there are removed.
"""
import contextlib
import errno
import fcntl
import json
import os
import pathlib
import shutil
import stat

from stdm_drake.errors import InputError
from stdm_drake.files import (NO_ROOM, check_room, nearest_existing, no_room_error, remove_stale_temporaries,
                              write_text_atomic)
from stdm_drake.interrupts import protected

# Written into every output folder a command fills, and looked for before replacing one.
FOLDER_MARKER = ".stdm-drake-output"
# The first line of every HTML file stdm-drake writes: "<!-- written by stdm-drake COMMAND -->" (`html_marker`;
# older files and the library's: without the command).
HTML_MARKER = "<!-- written by stdm-drake -->"
HTML_PREFIX = "<!-- written by stdm-drake"
IDENTIFIED_MARKER = "# An identified robot, written by `stdm-drake identify`"   # first line of identified.yaml
NATIVE_MARKER = "# stdm-drake export --target drake:"   # first line of a Drake-native model file
CONTROLLER_MARKER = "# stdm-drake controller 1"   # first line of a controller file (closed_loop/controller_file.py)
MARKERS = {"identified": IDENTIFIED_MARKER, "native": NATIVE_MARKER, "controller": CONTROLLER_MARKER}   # first lines
OUTPUT_KINDS = ("dataset", "json", "identified", "html", "onnx", "native", "controller")
PRODUCT_KINDS = {"dataset": "models trained on it record its SHA-256", "identified": "grey boxes trained on it name it"}
DATASET_FORMAT = "stdm-drake-dataset"  # the HDF5 "format" attribute of every dataset (stdm_drake.data.dataset)
WRITTEN_BY = "written_by"   # the HDF5 attribute (and JSON key) naming the command: "stdm-drake COMMAND"
COMMAND_LINE = "command: "  # the folder marker's line naming the command

# while a command runs: {"command": name, "arguments": the rest of its line, "locks": {path: (fd, lock file, the
# folders made for it)}, "made": output folders (and parents) that `mark_output_folder` created, deepest first}
_running: dict | None = None
_held_locks: dict = {}   # every lock this process holds (as "locks" above): `release_locks`


@contextlib.contextmanager
def command_outputs(command: str, arguments: list[str] = (), options=None):
    """While `command` (a CLI command's name; `arguments`: its line's rest; `options`: its option strings) runs:
    outputs are checked against the command that wrote them, marked with it, locked until the block ends. A failed
    command (an error, a signal) leaves no output folder it made that holds nothing but the marker and empty folders."""
    global _running
    outer, _running = _running, dict(command=command, arguments=list(arguments), locks={}, made=[], options=options)
    try:
        yield
    except BaseException:
        for folder in _running["made"]:
            if _holds_only_its_marker(folder):
                shutil.rmtree(folder, ignore_errors=True)
        raise
    finally:
        running, _running = _running, outer
        release_locks(running["locks"])


def release_locks(locks: dict | None = None) -> None:
    """Remove the lock files of `locks` (a run's, path -> entry; None: every one this process holds, as the CLI does
    after a signal, which may have cut a run's own release short) still held, then the folders made for them that
    stayed empty; a signal meanwhile is raised once every lock file is gone, not between two of them."""
    with protected():
        released = [_held_locks.pop(key) for key in list(_held_locks if locks is None else locks) if key in _held_locks]
        for fd, lock_file, _ in released:
            with contextlib.suppress(OSError):
                os.unlink(lock_file)
            os.close(fd)
        for _, _, made in released:   # (after every lock file: two outputs may share a folder)
            _remove_empty(made)


def _remove_empty(folders) -> None:
    """Remove `folders` (deepest first: the folders made for a lock) that stayed empty."""
    for folder in folders:
        with contextlib.suppress(OSError):
            folder.rmdir()


def running_command(with_arguments: bool = False):
    """The CLI command now running (None: used as a library); `with_arguments`: its line after `stdm-drake`, a list."""
    line = None if _running is None else [_running["command"], *_running["arguments"]]
    return line if with_arguments or line is None else line[0]


def running_options() -> frozenset | None:
    """The option strings of the CLI command now running ("--train", "-o", ...); None as a library or unknown."""
    return None if _running is None else _running.get("options")


def written_by() -> str:
    """What an output records of the command that wrote it: "stdm-drake COMMAND" ("stdm-drake" from the library)."""
    command = running_command()
    return "stdm-drake" if command is None else f"stdm-drake {command}"


def html_marker() -> str:
    """The first line of an HTML file written now."""
    return f"{HTML_PREFIX} {running_command()} -->" if running_command() else HTML_MARKER


def lock_output(option: str, path) -> None:
    """Lock `path` for this run (a lock file `.NAME.lock` beside it; in it for a folder whose parent cannot be
    written) and remove the temporary files a killed run left for it; InputError naming the process if another
    run holds it."""
    if _running is None:
        return
    path = pathlib.Path(os.path.realpath(path))   # (the file itself, whatever link or alias names it)
    key = str(path)
    if key in _running["locks"]:
        return
    lock_file = path.parent / f".{path.name}.lock"
    if path.is_dir() and not os.access(lock_file.parent, os.W_OK):   # a folder in a folder this user cannot write
        lock_file = path / f"{FOLDER_MARKER}.lock"
    made = [folder for folder in lock_file.parents if not folder.exists()]   # removed again if still empty

    def open_lock_file() -> int:
        try:
            lock_file.parent.mkdir(parents=True, exist_ok=True)
            return os.open(lock_file, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as error:   # (no inode or block left for the lock file: the output is named, not the lock)
            failure = no_room_error(path, error) if error.errno in NO_ROOM else error   # (before its folders go)
            _remove_empty(made)
            raise failure from None
    with protected():   # (a signal once the lock file is made is raised when it is recorded: the end removes it)
        fd = open_lock_file()
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError as error:
                holder = os.pread(fd, 64, 0).decode(errors="replace").strip()
                os.close(fd)
                if error.errno not in (errno.EWOULDBLOCK, errno.EACCES):
                    raise
                who = (f"another stdm-drake run (process {holder})" if holder.isdigit() else
                       f"another process (it locks {lock_file} and does not say which)")
                raise InputError(f"{option} {path} is being written by {who}; wait for it to end or choose another "
                                 "path") from None
            with contextlib.suppress(FileNotFoundError):   # (removed by the run that held it just before: lock anew)
                if os.fstat(fd).st_ino == os.stat(lock_file).st_ino:
                    break
            os.close(fd)
            fd = open_lock_file()
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        _running["locks"][key] = _held_locks[key] = (fd, lock_file, made)
    if (path / FOLDER_MARKER).is_file():   # (only in a folder stdm-drake wrote: never a user's files)
        remove_stale_temporaries(path, recursive=True)
    remove_stale_temporaries(path.parent, path.name)


def _same_file(a: pathlib.Path, b: pathlib.Path) -> bool:
    try:
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:
        return False


def _check_parent(option: str, path: pathlib.Path, folder: pathlib.Path | None = None) -> None:
    """The folder `path` goes in (or the new `folder` that is itself) is a folder (or can be made one), writable."""
    existing = nearest_existing(folder if folder is not None else path.absolute().parent, broken_links=True)
    if not existing.is_dir():
        raise InputError(f"{option} {path}: {existing} is not a folder")
    if not os.access(existing, os.W_OK | os.X_OK):
        raise InputError(f"{option} {path}: cannot write in {existing} (permission denied)")


def _check_not_input(option: str, path: pathlib.Path, inputs, folder: bool = False) -> None:
    """An output is none of the inputs; a `folder` output holds none of them (the command replaces files in it)."""
    for source in (pathlib.Path(source) for source in inputs if source is not None):
        if _same_file(path, source) or path.absolute() == source.absolute():
            raise InputError(f"{option} {path} is one of the command's inputs ({source}); choose another path")
        if folder and (pathlib.Path(os.path.realpath(source)).is_relative_to(os.path.realpath(path))
                       or source.absolute().is_relative_to(path.absolute())):
            raise InputError(f"{option} {path} holds the input {source}, and the command replaces files there; move "
                             "the input out or choose another folder")


def _writer_of(path: pathlib.Path, kind: str) -> str | None:
    """Who wrote the regular file at `path`, an output of `kind` ("dataset", "json", "identified", "html"):
    "stdm-drake COMMAND", "stdm-drake" (an older file that does not name its command) or None (not stdm-drake)."""
    try:
        if kind == "dataset":
            import h5py
            with h5py.File(path, "r") as f:
                if f.attrs.get("format") != DATASET_FORMAT:
                    return None
                writer = f.attrs.get(WRITTEN_BY, "stdm-drake")
                return writer.decode() if isinstance(writer, bytes) else str(writer)
        if kind == "json":
            with open(path, encoding="utf-8") as f:
                data = json.load(f)
            writer = str(data.get(WRITTEN_BY, "")) if isinstance(data, dict) else ""
            return writer if writer.startswith("stdm-drake") else None
        if kind in MARKERS:   # (`identify` writes identified robots, `export` the others)
            with open(path, encoding="utf-8", errors="replace") as f:
                command = "identify" if kind == "identified" else "export"
                return f"stdm-drake {command}" if f.readline().startswith(MARKERS[kind]) else None
        if kind == "onnx":   # (only a .onnx file is read: onnx.load parses the whole file)
            return _onnx_writer(path) if path.suffix.lower() == ".onnx" else None
        if kind == "html":
            with open(path, encoding="utf-8", errors="replace") as f:
                line = f.readline().strip()
            if not (line.startswith(HTML_PREFIX) and line.endswith("-->")):
                return None
            return line[len("<!-- written by "):-len("-->")].strip()
    except (OSError, ValueError):
        return None
    raise ValueError(f"unknown output kind {kind!r}")


def _onnx_writer(path: pathlib.Path) -> str | None:
    import onnx
    try:
        writer = {p.key: p.value for p in onnx.load(str(path), load_external_data=False).metadata_props}[WRITTEN_BY]
    except Exception:   # (protobuf's DecodeError and onnx's own errors: not an ONNX file; no writer recorded)
        return None
    return writer if writer.startswith("stdm-drake") else None


def _other_command(writer: str) -> str | None:
    """The other CLI command `writer` ("stdm-drake COMMAND") names, if it names one and it is not the one
    running."""
    command = writer.removeprefix("stdm-drake").strip()
    running = running_command()
    return command if command and running and command != running else None


def check_output_file(option: str, path, *, kind: str, inputs=(), force: bool = False) -> pathlib.Path | None:
    """Check a file the command will write (option: its flag, for messages; kind: "dataset", "json",
    "identified", "html", "onnx" or "native"; inputs: the files the command reads) and lock it while the command runs.
    Returns the path (None stays None)."""
    if path is None:
        return None
    path = pathlib.Path(path)
    _check_not_input(option, path, inputs)
    if path.exists() or path.is_symlink():
        if _is_symlink_loop(path):
            raise InputError(f"{option} {path} is a symlink loop (its links point at each other)")
        mode = os.stat(path).st_mode if path.exists() else 0
        if path.is_dir():
            raise InputError(f"{option} {path} is a folder; give a file path")
        if not stat.S_ISREG(mode):
            raise InputError(f"{option} {path} is not a regular file (a device, pipe or broken link); "
                             "give a file path")
        writer = _writer_of(path, kind)
        if not force and writer is None:
            other = next((found for other_kind in OUTPUT_KINDS if other_kind != kind
                          for found in [_writer_of(path, other_kind)] if found), None)
            ancestor = _marked_ancestor(path, running_command())   # (results from before they named their command)
            if not other and ancestor is not None:
                other = f"stdm-drake {ancestor[1]}"
            if other and other.removeprefix("stdm-drake").strip() == running_command():
                raise InputError(f"{option} {path} is another kind of output of `{other}`; choose another path or "
                                 "pass --force to replace it")
            if other:   # (another kind of output, or a file of another command's folder)
                raise InputError(f"{option} {path} was written by `{other}`; choose another path or pass --force to "
                                 "replace it")
            raise InputError(f"{option} {path} exists and stdm-drake did not write it; pass --force to replace it")
        if not force and (_other_command(writer) or kind in PRODUCT_KINDS):
            what = f"was written by `{writer}`" if _other_command(writer) else f"exists and {PRODUCT_KINDS[kind]}"
            raise InputError(f"{option} {path} {what}; choose another path or pass --force to replace it")
        if not os.access(path, os.W_OK) and not os.access(path.parent, os.W_OK):
            raise InputError(f"{option} {path}: cannot replace it (permission denied)")
    _check_parent(option, path)
    check_room(option, path, path.absolute().parent)
    lock_output(option, path)
    return path


def folder_writer(path) -> str | None:
    """The command whose marker is in folder `path` ("" for a marker that does not name one), or None."""
    try:
        text = (pathlib.Path(path) / FOLDER_MARKER).read_text(encoding="utf-8", errors="replace")
    except OSError:
        return None
    for line in text.splitlines():
        if line.startswith(COMMAND_LINE):
            return line[len(COMMAND_LINE):].strip()
    return ""


# The result files each command's folder holds (runs before the folder marker named its command are known by
# them): a folder holding another command's is that command's.
COMMAND_RESULTS = {"train": ("summary.json",), "sine-sum": ("results.json", "summary.md", "table1.csv"),
                   "mpc": ("mpc.json", "mpc.csv"), "compare": ("compare.json", "compare.csv"), "reproduce": ("report.md", "cache", "sine_sum", "results.json")}
# (a reproduce run's report: what makes its folder a finished run's for `fresh_default_folder`; its cache is work)
FINISHED_RESULTS = {**COMMAND_RESULTS, "reproduce": ("report.md", "report.html")}


def _older_owner(path: pathlib.Path, command: str | None) -> tuple[str, str] | None:
    """(the other command, its result's name) whose results (COMMAND_RESULTS, beyond the files `command` writes
    too) the unmarked or older folder `path` holds, or None."""
    own = set(COMMAND_RESULTS.get(command, ()))
    for other, names in COMMAND_RESULTS.items():
        if other == command:
            continue
        for name in sorted(set(names) - own):
            if (path / name).exists():
                return other, name
    return None


def _marked_ancestor(path: pathlib.Path, command: str | None = None) -> tuple[pathlib.Path, str] | None:
    """(folder, command) of the nearest marked folder above `path` (the real one: whatever link names it)
    that is another command's than `command`: its marker names it, or (an older marker naming none) its result
    files do (COMMAND_RESULTS); None when there is none."""
    for parent in pathlib.Path(os.path.realpath(path)).parents:
        writer = folder_writer(parent)
        if writer == "":
            writer = (_older_owner(parent, command) or (None,))[0]
        if writer and writer != command:
            return parent, writer
    return None


def check_output_folder(option: str, path, *, inputs=(), force: bool = False) -> pathlib.Path:
    """Check a folder the command will fill and lock it while the command runs: missing, empty, marked by
    this command (or by an older run that did not name its command), holding this command's result files
    (COMMAND_RESULTS, from runs before the marker) and no other's, or --force. A folder that is or holds one
    of the inputs, an existing file, another command's folder or an existing folder inside another command's
    is refused."""
    path = pathlib.Path(path)
    _check_not_input(option, path, inputs, folder=True)
    command = running_command()
    if path.exists() or path.is_symlink():
        if _is_symlink_loop(path):
            raise InputError(f"{option} {path} is a symlink loop (its links point at each other)")
        if not path.is_dir():
            raise InputError(f"{option} {path} exists and is not a folder; give a folder path")
        writer = folder_writer(path)
        other = writer if writer and command and writer != command else None
        if not writer and command:
            found = _older_owner(path, command)
            if not force and found:   # (a folder from before markers, or a user's own: name the file)
                raise InputError(f"{option} {path} holds {found[1]}, the name of a `stdm-drake {found[0]}` result, "
                                 "and no marker naming its command; choose another folder or pass --force to write into it")
            ancestor = _marked_ancestor(path, command)
            other = ancestor[1] if ancestor is not None else None
        if not force and other:
            raise InputError(f"{option} {path} holds the outputs of `stdm-drake {other}`; choose another folder "
                             "or pass --force to write into it")
        own = any((path / name).exists() for name in COMMAND_RESULTS.get(command, ()))
        # an older marker does not name its command: the folder is this command's if it holds its results
        ours = bool(writer) or own or (writer == "" and {child.name for child in path.iterdir()} <= {FOLDER_MARKER})
        if not force and not ours and any(path.iterdir()):
            raise InputError(f"{option} {path} is a folder stdm-drake did not write (not empty); choose another "
                             "or pass --force to write into it")
        if not os.access(path, os.W_OK | os.X_OK):
            raise InputError(f"{option} {path}: cannot write in it (permission denied)")
    else:
        _check_parent(option, path, folder=path.absolute())
    check_room(option, path, path.absolute())
    lock_output(option, path)
    return path


def _is_symlink_loop(path: pathlib.Path) -> bool:
    try:
        os.stat(path)
    except OSError as error:
        return error.errno == errno.ELOOP
    return False


def _holds_only_its_marker(folder: pathlib.Path) -> bool:
    """Whether `folder` holds nothing but a folder marker (its own or a subfolder's) and empty folders."""
    for root, folders, names in os.walk(folder):
        if any(os.path.islink(os.path.join(root, name)) for name in folders) or any(name != FOLDER_MARKER
                                                                                      for name in names):
            return False
    return True


def mark_output_folder(path) -> None:
    """Create the output folder if needed and mark it as the running command's."""
    path = pathlib.Path(path)
    if _running is not None:
        _running["made"].extend(folder for folder in (path, *path.absolute().parents) if not folder.exists())
    path.mkdir(parents=True, exist_ok=True)
    command = running_command()
    if (path / FOLDER_MARKER).exists() and (command is None or folder_writer(path) == command):
        return
    try:
        write_text_atomic(path / FOLDER_MARKER, "This folder holds stdm-drake outputs; stdm-drake may replace what "
                          "is in it.\n" + (f"{COMMAND_LINE}{command}\n" if command else ""))
    except (OSError, ValueError):
        with contextlib.suppress(OSError):
            path.rmdir()   # (made for nothing: only if it is empty)
        raise


def fresh_default_folder(default, command: str) -> pathlib.Path:
    """The folder `command` writes to when the user names none: `default` (e.g. out/mpc) unless it holds one of
    the command's result files (FINISHED_RESULTS: a finished run's), else the first of default-2, default-3, ...
    that holds none, so a second run never replaces the first run's results, while a run stopped before its
    results (its cached work kept) continues in its folder (a folder the user names: `check_output_folder`)."""
    default = pathlib.Path(default)
    candidate, number = default, 1
    while candidate.exists() and (not candidate.is_dir()
                                  or any((candidate / name).exists() for name in FINISHED_RESULTS[command])):
        number += 1
        candidate = default.with_name(f"{default.name}-{number}")
    return candidate


def add_force_argument(parser) -> None:
    parser.add_argument("--force", action="store_true",
                        help="replace an existing dataset or identified robot (what was made from it would no longer "
                             "match it), or a file another command or a user wrote; a rerun replaces its own others")
