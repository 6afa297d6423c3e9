"""UR RTDE logs as CSV files: a header row of RTDE field names, then one row per controller cycle; space
delimited (the RTDE client library's recorder) or comma delimited (ur_rtde's file recording). Fields read
(n joints, indexed from 0): timestamp (s), actual_q_i (rad), actual_qd_i (rad/s); the torque from
target_moment_i (N m) or actual_current_i (A) times the mapping's torque constants; the plan from
target_q_i, target_qd_i, target_qdd_i when all three are there (the paper's real-robot protocol); the modes
from robot_mode, safety_mode and runtime_state when there (a row runs normally in robot mode 7 RUNNING, safety
mode 1 NORMAL or 2 REDUCED, runtime state 2 PLAYING). Other fields are ignored; blank lines are skipped, and every
other line must hold as many fields as the header. Read in blocks of lines (`rows`): memory does not grow with
the file."""
import itertools
import pathlib

import numpy as np

from stdm_drake.data.logs.rows import Rows
from stdm_drake.errors import InputError

# field -> its values while the robot runs normally (a change of any of them starts a new trajectory)
MODE_FIELDS = {"robot_mode": (7,), "safety_mode": (1, 2), "runtime_state": (2,)}
BLOCK_ROWS = 65536


def read_header(path) -> tuple[list, str | None]:
    """(field names, delimiter: "," or None for whitespace) of an RTDE CSV file."""
    path = pathlib.Path(path)
    if path.is_dir():
        raise InputError(f"RTDE log {path} is a folder, not a CSV file")
    with open(path, encoding="utf-8-sig", errors="replace") as file:
        line = file.readline(1 << 20)
    if not line.strip():
        raise InputError(f"RTDE log {path}: empty, or no header row of field names")
    delimiter = "," if "," in line else None
    names = [name.strip() for name in (line.split(",") if delimiter else line.split())]
    if "timestamp" not in names:
        raise InputError(f"RTDE log {path}: its header has no timestamp field (first fields: {names[:4]}); not an "
                         "RTDE recording")
    return names, delimiter


def looks_like_rtde(path) -> bool:
    """Whether `path` is a text file whose first line names RTDE fields."""
    try:
        with open(path, encoding="utf-8-sig", errors="replace") as file:
            line = file.readline(1 << 16)
    except (OSError, UnicodeError):
        return False
    names = line.replace(",", " ").split()
    return "timestamp" in names and any(name.startswith("actual_q_") for name in names)


def columns(names: list, path, joints: int, mapping) -> dict:
    """Field -> column index of every field the import reads, checked: the robot's joints all there (and no
    more joints than it has), the torque source's fields, the plan's three complete or absent."""
    where = {name: index for index, name in enumerate(names)}
    if len(where) != len(names):
        duplicated = sorted({name for name in names if names.count(name) > 1})
        raise InputError(f"RTDE log {path}: fields named twice in the header: {duplicated}")
    logged = sorted(int(name.rsplit("_", 1)[1]) for name in names
                    if name.startswith("actual_q_") and name.rsplit("_", 1)[1].isdigit())
    if logged and max(logged) >= joints:
        raise InputError(f"RTDE log {path}: it logs {max(logged) + 1} joints (actual_q_0..{max(logged)}), the robot has "
                         f"{joints}; pass the logged arm's --robot")
    torque = "target_moment" if mapping.torque_source == "target_moment" else "actual_current"
    wanted = {"t": ["timestamp"], "q": [f"actual_q_{j}" for j in range(joints)],
              "v": [f"actual_qd_{j}" for j in range(joints)], "tau": [f"{torque}_{j}" for j in range(joints)]}
    for key, fields in wanted.items():
        missing = [field for field in fields if field not in where]
        if missing:
            hint = " (classic UR arms log no joint torque: --torque-source current with torque constants)" \
                if key == "tau" and torque == "target_moment" else ""
            raise InputError(f"RTDE log {path}: fields missing from the header: {', '.join(missing[:4])}"
                             f"{' ...' if len(missing) > 4 else ''}{hint}")
    plan = {"q_planned": "target_q", "v_planned": "target_qd", "qdd_planned": "target_qdd"}
    present = {key: all(f"{prefix}_{j}" in where for j in range(joints)) for key, prefix in plan.items()}
    if any(present.values()) and not all(present.values()):
        absent = [plan[key] for key, there in present.items() if not there]
        raise InputError(f"RTDE log {path}: the plan is incomplete: no {', '.join(f'{p}_*' for p in absent)} (log "
                         "target_q, target_qd and target_qdd, or none of them)")
    if all(present.values()):
        wanted.update({key: [f"{prefix}_{j}" for j in range(joints)] for key, prefix in plan.items()})
    modes = [field for field in MODE_FIELDS if field in where]
    if modes:
        wanted["modes"] = modes
    return {key: [where[field] for field in fields] for key, fields in wanted.items()} | {"mode_fields": modes}


def rows(path, joints: int, mapping, block_rows: int = BLOCK_ROWS):
    """The log's rows as `Rows` blocks of up to `block_rows` (tau: the torque source's column, currents in A
    until the importer scales them); a malformed line is an InputError naming it (line numbers count the header as 1)."""
    path = pathlib.Path(path)
    names, delimiter = read_header(path)
    found = columns(names, path, joints, mapping)
    mode_fields = found.pop("mode_fields")
    order = [index for key in found for index in found[key]]
    spans, start = {}, 0
    for key in found:
        spans[key] = slice(start, start + len(found[key]))
        start += len(found[key])
    with open(path, encoding="utf-8-sig", errors="replace") as file:
        file.readline()
        line = 2
        while True:
            lines = list(itertools.islice(file, block_rows))
            if not lines:
                break
            numbers = np.arange(line, line + len(lines))
            line += len(lines)
            filled = [index for index, text in enumerate(lines) if text.strip()]
            if len(filled) < len(lines):      # blank lines: skipped, the others keep their line numbers
                lines, numbers = [lines[index] for index in filled], numbers[filled]
            if not lines:
                continue
            _check_field_counts(lines, delimiter, len(names), path, numbers)
            values = _parse(lines, delimiter, order, path, numbers)
            if not np.all(np.isfinite(values)):
                bad = int(np.flatnonzero(~np.all(np.isfinite(values), axis=1))[0])
                raise InputError(f"RTDE log {path}: line {numbers[bad]} holds NaN or inf")
            block = {key: values[:, span] for key, span in spans.items()}
            mode = running = None
            if "modes" in block:
                codes = block["modes"]
                mode = (codes * (1000 ** np.arange(codes.shape[1]))).sum(axis=1).astype(np.int64)
                running = np.all([np.isin(codes[:, column], MODE_FIELDS[field])
                                  for column, field in enumerate(mode_fields)], axis=0)
            yield Rows(t=block["t"][:, 0], q=block["q"], v=block["v"], tau=block["tau"], where=numbers,
                       q_planned=block.get("q_planned"), v_planned=block.get("v_planned"),
                       qdd_planned=block.get("qdd_planned"), mode=mode, running=running)


def _check_field_counts(lines: list, delimiter, fields: int, path, numbers: np.ndarray) -> None:
    """InputError naming the first of `lines` (none blank) whose field count is not the header's."""
    separator = delimiter or " "
    counts = np.fromiter((text.count(separator) for text in lines), dtype=np.int64, count=len(lines)) + 1
    for index in np.flatnonzero(counts != fields):   # (whitespace runs: count the fields themselves)
        found = len(lines[index].split(delimiter) if delimiter else lines[index].split())
        if found != fields:
            raise InputError(f"RTDE log {path}: line {numbers[index]} has {found} fields, the header {fields} (a "
                             "truncated or hand-edited file?)")


def _parse(lines: list, delimiter, order: list, path, numbers: np.ndarray) -> np.ndarray:
    """The chosen columns of `lines` (none blank, every one with the header's fields) as floats; a field that is
    not a number is an InputError naming its line."""
    try:
        values = np.loadtxt(lines, delimiter=delimiter, usecols=order, ndmin=2, dtype=float, comments=None)
    except ValueError:
        values = None
    if values is not None and len(values) == len(lines):
        return values
    for index, text in enumerate(lines):   # (only on an error: find the line)
        cells = text.split(delimiter) if delimiter else text.split()
        try:
            [float(cells[column]) for column in order]
        except ValueError:
            raise InputError(f"RTDE log {path}: line {numbers[index]} holds a field that is not a number") from None
    raise InputError(f"RTDE log {path}: lines {numbers[0]}..{numbers[-1]} do not read as numbers")
