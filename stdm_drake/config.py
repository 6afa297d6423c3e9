"""Typed YAML configs: dataclass schemas loaded with Drake's `yaml_load_typed`.

Bad files (missing, malformed YAML, unknown keys, wrong types, not a mapping, values the schema's
`validate()` rejects) raise InputError with one line that names the file.
"""
import dataclasses
import pathlib
import re

import numpy as np
import yaml
from pydrake.common.yaml import yaml_load_typed

from stdm_drake.errors import InputError, warn
from stdm_drake.files import size_text
from stdm_drake.paths import check_input_file
from stdm_drake.yaml_values import MAX_SETTINGS_DEPTH, YAML_LOADER, boolean_words_as_text, check_quoted_numbers



# A number on a command line as its digits say it: ASCII decimal digits (Python's int() and float() also read `1_0` as 10,
# `٢` as 2 and `０.５` as 0.5, which no one means as the number)
DECIMAL_INT = re.compile(r"[-+]?[0-9]+", re.ASCII)
DECIMAL_FLOAT = re.compile(r"[-+]?(?:(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][-+]?[0-9]+)?|inf|infinity|nan)",
                           re.ASCII | re.IGNORECASE)


def decimal_number(text: str, kind: type = float):
    """`text` as an int or float (`kind`) where it is written in ASCII decimal digits (an optional sign, point and
    exponent; inf and nan for a float), padded with spaces or tabs at most; ValueError otherwise."""
    written = text.strip(" \t")
    if not (DECIMAL_INT if kind is int else DECIMAL_FLOAT).fullmatch(written):
        raise ValueError(f"{text!r} is not a number in decimal ASCII digits")
    return kind(written)


def one_line(error: BaseException) -> str:
    """An exception's message squeezed onto one line (its type name if it has none)."""
    return " ".join(str(error).split()) or type(error).__name__


# A settings file (MPC, controller, sensor, plan, plant effects, training) states a few dozen values: a few kB.
# One past this is refused before it is read, since the YAML parser would spend minutes on it (a 50 MB list).
MAX_SETTINGS_BYTES = 1 << 20


def load_yaml_config(path, schema, what: str = "config", old_layouts: dict | None = None, defaults=None,
                     validate: bool = True):
    """Load `path` into a new instance of `schema` (a dataclass, or a Drake config type); keys left out
    keep the values of `defaults` (default: `schema()`); its `validate()`, if it has one, unless `validate` is
    False (settings that flags complete or override: the caller validates what they make together).

    what: how errors name the file's contents, e.g. "tracking spec". old_layouts: {field: (types by
    kind, tag hint)} for Union-typed fields whose files may still be in the layout before tags (`field:`
    holding `kind:` and the fields, or, for the field "", the whole file): read by `from_kind_layout`.
    """
    path = check_input_file(path, what)
    if path.is_file() and (size := path.stat().st_size) > MAX_SETTINGS_BYTES:
        raise InputError(f"{path}: {size_text(size)}, more than any {what} holds (a few kB; at most "
                         f"{size_text(MAX_SETTINGS_BYTES)} is read)")
    check_nesting(path, what)
    check_quoted_numbers(path, schema)
    config = _load_old_layout(path, schema, what, old_layouts) if old_layouts else None
    if config is None:
        text = boolean_words_as_text(path, schema)   # (`per_group: on`: the words as written, not YAML 1.1's True)
        try:
            config = yaml_load_typed(schema=schema, defaults=schema() if defaults is None else defaults,
                                     **(dict(filename=str(path)) if text is None else dict(data=text)))
        except Exception as error:  # the YAML parser and Drake's schema checks raise several types
            raise InputError(f"{path}: malformed {what}: {one_line(error)}") from None
        if not isinstance(config, schema):
            raise InputError(f"{path}: malformed {what}: expected a mapping of {schema.__name__} fields")
    if validate and hasattr(config, "validate"):
        try:
            config.validate()
        except InputError as error:
            raise InputError(f"{path}: {error}") from None
    return config


def nested_too_deep(text: str) -> bool:
    """Whether YAML `text` nests mappings and lists more than MAX_SETTINGS_DEPTH levels deep, counted on the
    scanner's tokens up to the first level too deep (no recursion: a file nested thousands deep is measured, not
    parsed); False where it does not scan (the parser says why)."""
    if sum(text.count(mark) for mark in "[{:-?") <= MAX_SETTINGS_DEPTH:
        return False   # (each level opens at one of these marks: too few of them, no scan needed)
    opening = (yaml.BlockMappingStartToken, yaml.BlockSequenceStartToken, yaml.FlowMappingStartToken,
               yaml.FlowSequenceStartToken)
    closing = (yaml.BlockEndToken, yaml.FlowMappingEndToken, yaml.FlowSequenceEndToken)
    depth = 0
    try:
        for token in yaml.scan(text, Loader=yaml.SafeLoader):
            depth += isinstance(token, opening) - isinstance(token, closing)
            if depth > MAX_SETTINGS_DEPTH:
                return True
    except yaml.YAMLError:
        return False
    return False


def check_nesting(path, what: str) -> None:
    """InputError (one line) where the file at `path` nests mappings and lists deeper than MAX_SETTINGS_DEPTH."""
    try:
        text = pathlib.Path(path).read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError):
        return   # (the typed load says why)
    if nested_too_deep(text):
        raise InputError(f"{path}: nests lists or mappings more than {MAX_SETTINGS_DEPTH} levels deep, deeper than any "
                         f"{what} (a few levels)")


class TaggedMapping(dict):
    """A YAML mapping that carried a tag (`!Pid {...}`): `tag` is its name."""
    tag = ""


class _TagsAsPlainValues(YAML_LOADER):
    """A YAML loader that reads a tagged node (`!Pid {...}`) as its plain mapping (a TaggedMapping),
    list or scalar."""


def _plain(loader, suffix, node):
    if isinstance(node, yaml.MappingNode):
        mapping = TaggedMapping(loader.construct_mapping(node, deep=True))
        mapping.tag = suffix
        return mapping
    if isinstance(node, yaml.SequenceNode):
        return loader.construct_sequence(node, deep=True)
    return loader.construct_scalar(node)


_TagsAsPlainValues.add_multi_constructor("!", _plain)


def _number_or_text(kind):
    """The standard number constructor of `kind` ("int", "float"), the scalar's text where YAML cannot read it so
    (`!!float 0o1`): the layout is seen, and the setting's check names the value."""
    standard = getattr(yaml.SafeLoader, f"construct_yaml_{kind}")

    def construct(loader, node):
        try:
            return standard(loader, node)
        except (ValueError, IndexError):   # (`!!int ""`: PyYAML indexes the empty text)
            return loader.construct_scalar(node)
    return construct


for _kind in ("int", "float"):
    _TagsAsPlainValues.add_constructor(f"tag:yaml.org,2002:{_kind}", _number_or_text(_kind))


def read_yaml_document(path):
    """A YAML file's document as plain Python values, tags ignored (to see its layout before the typed
    load); None when it cannot be read or parsed, is no regular file (a FIFO: reading would block) or is
    larger or deeper than any settings file (MAX_SETTINGS_BYTES, MAX_SETTINGS_DEPTH); the typed load then says why."""
    if not pathlib.Path(path).is_file() or pathlib.Path(path).stat().st_size > MAX_SETTINGS_BYTES:
        return None
    try:
        text = pathlib.Path(path).read_text()
        return yaml.load(text, Loader=_TagsAsPlainValues) if not nested_too_deep(text) else None
    except (OSError, UnicodeDecodeError, yaml.YAMLError, ValueError, IndexError):   # (`!!float 0x10`, `!!int ""`)
        return None


def file_keys(path) -> set:
    """The top-level keys a YAML file sets (none without a file, or for one that is no mapping): the settings
    the user gave there, whatever their values (a key the run would ignore is refused by the caller)."""
    document = read_yaml_document(path) if path is not None else None
    return set(document) if isinstance(document, dict) else set()


def _load_old_layout(path: pathlib.Path, schema, what: str, old_layouts: dict):
    """`schema` from a file in the layout before tags (see load_yaml_config; not yet validated), or None
    when it is not one."""
    document = read_yaml_document(path)
    if not isinstance(document, dict):
        return None
    first = dataclasses.fields(schema)[0].name   # the field the whole file holds, for the layout ""
    old = {name: layout for name, layout in old_layouts.items()
           if (first not in document if name == "" else
               isinstance(document.get(name), dict) and not isinstance(document.get(name), TaggedMapping))}
    if not old:
        return None
    if "" in old:   # the whole file is the one tagged field's value
        types, tagged = old[""]
        config = schema(**{first: from_kind_layout(document, types, path, tagged)})
    else:
        converted = {name: from_kind_layout(document.pop(name), old[name][0], f"{path}: {name}", old[name][1])
                     for name in old}
        try:
            config = yaml_load_typed(schema=schema, data=yaml.safe_dump(document), defaults=schema())
        except Exception as error:  # the YAML parser and Drake's schema checks raise several types
            raise InputError(f"{path}: malformed {what}: {one_line(error)}") from None
        for name, value in converted.items():
            setattr(config, name, value)
    return config


def check_joint_vector(label: str, values, *, count: int | None = None, nonnegative: bool = False) -> np.ndarray:
    """`values` (one per joint, or one for every joint) as a float array, or InputError unless they are
    finite (non-negative) numbers. count: the robot's joints: the result is (count,), a single value
    broadcast; None (config files checked before the robot is known): any non-empty length."""
    array = np.atleast_1d(np.asarray(values, dtype=float))
    kind = "finite non-negative" if nonnegative else "finite"
    if array.ndim != 1 or not array.size or not np.all(np.isfinite(array)) or (nonnegative and np.any(array < 0)):
        raise InputError(f"{label} must be {kind} numbers (one per joint, or one for all), got {values}")
    if count is not None:
        if array.size not in (1, count):
            raise InputError(f"{label} has {array.size} values; the robot has {count} joints (give {count}, or one "
                             "for all)")
        array = np.broadcast_to(array, (count,)).copy()
    return array


# The characters of a refused value `require` shows: a list of 40,000 joint names was one line of 400 kB
MAX_SHOWN_VALUE = 300


def require(condition: bool, message: str, value) -> None:
    """InputError "<message>, got <value>" unless `condition` holds (config validation); a long value shown by its
    first MAX_SHOWN_VALUE characters and its length."""
    if not condition:
        shown = repr(value)
        if len(shown) > MAX_SHOWN_VALUE:
            sized = isinstance(value, (list, tuple, dict, set))
            count = f"{len(value):,} entries" if sized else f"{len(shown):,} characters"
            shown = f"{shown[:MAX_SHOWN_VALUE]}... ({count})"
        raise InputError(f"{message}, got {shown}")


def from_kind_layout(mapping: dict, types: dict, where, tagged: str):
    """A config from a mapping in the layout before YAML tags (`kind: NAME` beside the fields; without
    one, the first kind, the default then), for the files written then: the instance of types[NAME]
    with the fields it has (fields only other kinds have, which that kind ignored, are dropped), and one
    warning line (`errors.warn`) saying how to write it now (`tagged`: e.g. "controller: !{}").
    InputError on an unknown kind or a field no kind has."""
    mapping = dict(mapping)
    given = "kind" in mapping
    kind = mapping.pop("kind", next(iter(types)))
    if kind not in types:
        raise InputError(f"{where}: kind must be one of {', '.join(types)}, got {kind!r}")
    target = types[kind]
    known = {field.name for cls in types.values() for field in dataclasses.fields(cls)}
    unknown = sorted(set(mapping) - known)
    if unknown:
        raise InputError(f"{where}: unknown fields {unknown}")
    own = {field.name for field in dataclasses.fields(target)}
    try:
        config = yaml_load_typed(schema=target, data=yaml.safe_dump({k: v for k, v in mapping.items() if k in own}),
                                 defaults=target())
    except Exception as error:  # Drake's schema checks raise several types
        raise InputError(f"{where}: {one_line(error)}") from None
    layout = f"uses the old `kind: {kind}` layout" if given else f"has no type tag (read as the default, {kind})"
    warn(f"stdm-drake: warning: {where} {layout}; write `{tagged.format(target.__name__)}` with its fields "
         "indented under it")
    return config
