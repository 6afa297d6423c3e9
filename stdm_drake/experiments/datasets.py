"""`stdm-drake reproduce`, stage 1, and the studies' datasets: collect a dataset unless a file collected with exactly
the same settings exists (`ensure_dataset`)."""
import json
import pathlib

from stdm_drake.errors import InputError


def _reusable_dataset(path: pathlib.Path, request):
    """The dataset at `path` if it is readable and was collected exactly as `request` asks (count, seed,
    robot, plant, sensor, controller, plan or excitation settings; package versions aside), else None."""
    from stdm_drake.collection.collect import collection_metadata   # lazy: pydrake, h5py
    from stdm_drake.data.dataset import load_dataset   # lazy: pydrake, h5py
    if not path.exists():
        return None
    try:
        dataset = load_dataset(path)
    except InputError:  # unreadable (e.g. truncated): it will be collected again
        return None
    expected = json.loads(json.dumps(collection_metadata(request)))
    expected.pop("package_versions")
    same = all(_agrees(dataset.metadata.record.get(key), value) for key, value in expected.items())
    return dataset if same else None


# sections whose presence itself is a setting: a plant with effects records them, one without does not
PRESENCE_MATTERS = ("effects",)


def _agrees(recorded, expected) -> bool:
    """Whether a recorded metadata value says what `expected` says: equal, or, for a section (a mapping),
    equal in every field both record (a field only one of them has was added or dropped by a later
    stdm-drake or Drake, such as Drake's plant settings or a controller kind's unused fields), except the
    fields of PRESENCE_MATTERS, which both record or neither."""
    if isinstance(recorded, dict) and isinstance(expected, dict):
        if any((key in recorded) != (key in expected) for key in PRESENCE_MATTERS):
            return False
        return all(_agrees(recorded[key], expected[key]) for key in recorded.keys() & expected.keys())
    return recorded == expected


def ensure_dataset(protocol: str, count: int, seed: int, folder: pathlib.Path, progress: bool,
                   name: str | None = None, **settings):
    """Collect the dataset (`collection_request` with its defaults plus `settings`, e.g. controller=PATH)
    unless a file of that name collected with exactly these settings exists."""
    from stdm_drake.collection.collect import collect, collection_request   # lazy: pydrake, h5py
    from stdm_drake.data.dataset import load_dataset   # lazy: pydrake, h5py
    from stdm_drake.data.writer import write_dataset   # lazy: pydrake, h5py
    path = folder / f"{name or protocol}_n{count}_seed{seed}.h5"
    request = collection_request(protocol, count=count, seed=seed, **settings)
    dataset = _reusable_dataset(path, request)
    if dataset is not None:
        return dataset
    trajectories, groups, metadata = collect(request, progress=progress)
    write_dataset(path, trajectories, groups, metadata)
    return load_dataset(path)
