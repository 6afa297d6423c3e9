"""Writing dataset files (the layout: `data.dataset`'s docstring): `DatasetWriter` one trajectory at a time,
atomically; `write_dataset` for trajectories in memory; `package_versions`, what a file records of the software
that wrote it."""
import contextlib
import json
import os
import pathlib
import re
import sys

import h5py
import numpy as np

from stdm_drake.data.dataset import FORMAT, FORMAT_VERSION, Trajectory
from stdm_drake.data.schema import PLANNED_ARRAYS, PROTOCOLS, check_trajectory
from stdm_drake.errors import InputError
from stdm_drake.files import atomic_path, check_free_space, json_default
from stdm_drake.interrupts import protected
from stdm_drake.outputs import WRITTEN_BY, written_by

# HDF5 crashes the process when the disk fills under it, so it never may: before each trajectory the writer
# checks that its arrays (plus HDF5's records of each, a bound), what HDF5 may still hold unwritten since its
# last flush, and a reserve for the file's header fit; it flushes every HDF5_FLUSH_BYTES.
HDF5_RESERVE_BYTES = 256 << 10
HDF5_BYTES_PER_ARRAY = 1024
HDF5_FLUSH_BYTES = 8 << 20
HDF5_HEADER_BYTES = 16 << 10   # the file's own header and metadata at the end, within the file size limit


def check_metadata(metadata: dict) -> float:
    """A dataset's metadata before anything is written: a known protocol and a positive sample period (s),
    which it returns."""
    if metadata.get("protocol") not in PROTOCOLS:
        raise InputError(f"metadata protocol must be one of {PROTOCOLS}, got {metadata.get('protocol')!r}")
    try:
        sample_period = float(metadata.get("sample_period", 0.0))
    except (TypeError, ValueError):
        sample_period = float("nan")
    if not (np.isfinite(sample_period) and sample_period > 0):
        raise InputError(f"metadata sample_period must be a positive number of seconds, got "
                         f"{metadata.get('sample_period')!r}")
    return sample_period


def hdf5_failure(error: BaseException) -> str:
    """The system's reason in an HDF5 write error ("File too large"), or its first 200 characters."""
    match = re.search(r"error message = '([^']*)'", str(error))
    return match.group(1) if match else " ".join(str(error).split())[:200]


class DatasetWriter:
    """Writes a dataset one trajectory at a time (memory: one trajectory), atomically: into a temporary file
    beside `path`, renamed onto it when the `with` block ends without an error (on any error no file and no
    temporary file is left). The metadata (protocol and sample period first, checked at once) may gain
    entries until the end (`metadata.update`): the header is written last.

        with DatasetWriter(path, metadata) as writer:
            writer.add(trajectory, group)
    """

    def __init__(self, path, metadata: dict):
        self.path = pathlib.Path(path)
        self.metadata = dict(metadata)
        self.sample_period = check_metadata(self.metadata)
        self.protocol = self.metadata["protocol"]
        self.count = 0
        self._planned = None   # whether the trajectories hold the plan (None: none written yet)
        self._atomic = self._file = None
        self._unflushed = 0    # bytes written to HDF5 since its last flush (an upper bound)
        self._size_at_flush = 0   # the temporary file's size then

    @property
    def has_plan(self) -> bool:
        """Whether the trajectories written so far hold the plan."""
        return bool(self._planned)

    def __enter__(self) -> "DatasetWriter":
        check_free_space(self.path, HDF5_RESERVE_BYTES)
        self._atomic = atomic_path(self.path)
        temp_name = self._temp = self._atomic.__enter__()
        try:
            with protected():
                self._file = h5py.File(temp_name, "w", libver=("earliest", "v110"), track_order=False)
                self._root = self._file.create_group("trajectories")
        except BaseException:
            self._atomic.__exit__(*sys.exc_info())
            raise
        return self

    def add(self, trajectory: Trajectory, group: int = 0) -> None:
        """Check and write the next trajectory (its index: the count so far)."""
        arrays = trajectory.arrays()
        name = f"{self.count:06d}"
        check_trajectory(name, arrays, self.protocol, self.sample_period)
        planned = any(key in arrays for key in PLANNED_ARRAYS)
        if self._planned is not None and planned != self._planned:
            raise InputError(f"trajectory {name}: {'has' if planned else 'lacks'} the plan the others "
                             f"{'lack' if planned else 'have'} (a dataset's trajectories all have it or none)")
        self._planned = planned
        arrays = {key: np.asarray(value, dtype=np.float64) for key, value in arrays.items()}
        size = sum(value.nbytes + HDF5_BYTES_PER_ARRAY for value in arrays.values())
        file_size = os.path.getsize(self._temp)
        on_disk = file_size - self._size_at_flush    # of what was written since the flush
        pending = max(0, self._unflushed - on_disk) + size
        check_free_space(self.path, pending + HDF5_RESERVE_BYTES, file_size + pending + HDF5_HEADER_BYTES)
        with protected():   # a signal inside an HDF5 write is swallowed or crashes it: raised after it instead
            entry = self._root.create_group(name)
            entry.attrs["group"] = int(group)
            for key in sorted(arrays):
                entry.create_dataset(key, data=arrays[key], track_times=False)
            self._unflushed += size
            if self._unflushed > HDF5_FLUSH_BYTES:
                self._file.flush()
                self._unflushed, self._size_at_flush = 0, os.path.getsize(self._temp)
        self.count += 1

    def __exit__(self, kind, error, trace):
        with protected():   # closed, then renamed or removed, whatever signal arrives meanwhile
            if error is not None:   # the block's error is the one to report: the file is closed and removed
                with contextlib.suppress(Exception):
                    self._file.close()
                return self._atomic.__exit__(kind, error, trace)
            try:
                try:
                    self._write_header()
                finally:
                    self._file.close()
            except (RuntimeError, OSError) as failure:   # HDF5 could not write its records (the file system)
                error = InputError(f"cannot write {self.path}: {hdf5_failure(failure)}; nothing was replaced")
                self._atomic.__exit__(InputError, error, None)
                raise error from None
            except Exception:
                self._atomic.__exit__(*sys.exc_info())
                raise
            return self._atomic.__exit__(None, None, None)

    def _write_header(self) -> None:
        if not self.count:
            raise InputError("a dataset needs at least one trajectory")
        attrs = self._file.attrs
        attrs["format"] = FORMAT
        attrs[WRITTEN_BY] = written_by()
        attrs["format_version"] = FORMAT_VERSION
        attrs["protocol"] = self.protocol
        attrs["sample_period"] = self.sample_period
        attrs["num_trajectories"] = self.count
        attrs["metadata_json"] = json.dumps(self.metadata, sort_keys=True, default=json_default)


def write_dataset(path, trajectories: list[Trajectory], groups, metadata: dict) -> pathlib.Path:
    """Validate and write a dataset atomically (`DatasetWriter`: each trajectory checked as it is added; on an
    error the temporary file goes).

    trajectories: the Trajectory of each (arrays named as in the module docstring).
    groups: (num_trajectories,) ints. metadata: JSON-serializable dict with at least
    "protocol" and "sample_period" (s). On any error no file (and no temp file) is left.
    """
    check_metadata(metadata)
    groups = np.asarray(groups, dtype=int)
    if groups.shape != (len(trajectories),):
        raise InputError(f"groups has shape {groups.shape}, expected ({len(trajectories)},)")
    with DatasetWriter(path, metadata) as writer:
        for traj, group in zip(trajectories, groups):
            writer.add(traj, int(group))
    return pathlib.Path(path)


def package_versions(*extra: str) -> dict:
    """The versions of the packages that shape a dataset (and of `extra` ones), as its metadata records them."""
    from importlib import metadata
    versions = {}
    for name in ("stdm-drake", "drake", "numpy", "h5py", "ruckig", "toppra", *extra):
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = None
    versions["python"] = ".".join(map(str, sys.version_info[:3]))
    return versions
