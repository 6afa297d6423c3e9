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
from stdm_drake.files import line_text, size_text
from stdm_drake.paths import check_input_file

# libyaml's parser where PyYAML was built with it (the wheels are) for composing and loading: a settings file of
# 300 kB took 44 s to refuse through the pure-Python parser, 5 s now (most of it Drake's typed load). libyaml gives
# a plain scalar the style "" (not None). The nesting scan stays pure Python: it stops at the first level too deep,
# where libyaml's scanner reads ahead and fails at its own limit of 1,000 levels first.
YAML_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


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
# Nesting levels of mappings and lists a settings file may hold (the deepest schema nests 4: an optimizer's
# settings in the MPC's); past it the YAML parsers recurse once per level (a 2,000-deep list: a RecursionError).
MAX_SETTINGS_DEPTH = 64


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
        try:
            config = yaml_load_typed(schema=schema, filename=str(path),
                                     defaults=schema() if defaults is None else defaults)
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


def check_quoted_numbers(path, schema) -> None:
    """InputError (one line naming the setting) where `path` quotes the value of a numeric or boolean field of
    `schema` (a dataclass; nested dataclasses and tagged variants followed): `samples: "100"` and `enabled: "false"`
    are strings in YAML, which Drake's typed load would read as the number or the boolean; also a number YAML 1.1
    reads otherwise (`024`), or a tagged number in digits of another script; an unreadable file is left to the
    typed load."""
    try:
        text = pathlib.Path(path).read_text(encoding="utf-8-sig")
        node = yaml.compose(text, Loader=YAML_LOADER)
    except (yaml.YAMLError, OSError, UnicodeDecodeError, RecursionError):
        return
    repeated = _repeated_key(node)
    if repeated is not None:
        key, first, second = repeated
        merge = " (merge several mappings with one: `<<: [*a, *b]`)" if key == "<<" else ""
        raise InputError(f"{path}: {line_text(key)} is given twice in one mapping (lines {first} and {second}); YAML "
                         f"keeps the last without a word, so give it once{merge}")
    found = _quoted_number(node, schema, "", text)
    if found is not None:
        where, value, how = found
        if how == "a single value where a list goes":
            raise InputError(f"{path}: {where} is {line_text(value[:80])}, {how}; write it as a list ([x]; a "
                             "per-joint setting takes one value x for every joint that way)")
        if how.startswith("which YAML reads as"):
            raise InputError(f"{path}: {where} is written {value}, {how}; write the number in plain decimal digits")
        if how == "which only YAML 1.1 reads as a boolean":
            raise InputError(f"{path}: {where} is written {value}, {how}; write true or false")
        if how.endswith(", not a boolean"):
            raise InputError(f"{path}: {where} is {value!r} {how}; write true or false without quotes or a tag")
        fix = "in ASCII digits" if how.endswith("another script") else {
            "in quotes": "without quotes", "read by YAML as text": "in ASCII digits"}.get(
            how, "without the tag" if how.startswith("tagged") else "in digits")
        raise InputError(f"{path}: {where} is {value!r} {how}, not a number; write the number {fix}")


def _repeated_key(node):
    """(the key, its first line, its second line) of the first mapping of `node` that states a key twice (a merge key
    `<<` too: merge several mappings with one, `<<: [*a, *b]`), or None. Each node visited once (aliases share them)."""
    pending, seen = [node], set()
    while pending:
        current = pending.pop()
        if current is None or id(current) in seen:
            continue
        seen.add(id(current))
        if isinstance(current, yaml.MappingNode):
            lines = {}
            for key, value in current.value:
                if isinstance(key, yaml.ScalarNode):   # (`<<` twice too: the second merge replaces the first)
                    if key.value in lines:
                        return key.value, lines[key.value], key.start_mark.line + 1
                    lines[key.value] = key.start_mark.line + 1
                pending += [key, value]
        elif isinstance(current, yaml.SequenceNode):
            pending += current.value
    return None


NUMBER_TAGS = ("tag:yaml.org,2002:int", "tag:yaml.org,2002:float", "tag:yaml.org,2002:null")
ASCII_NUMBER = re.compile(r"[-+]?(?:(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?|\.?inf|\.?nan)", re.IGNORECASE | re.ASCII)


MERGE_TAG = "tag:yaml.org,2002:merge"


def _pairs(node):
    """(key, value) nodes of mapping `node`, with those its merge keys bring in (`<<: *defaults`, `<<: [*a, *b]`)
    in their place: the values a typed load sees. A merge that is no mapping is left to the YAML loader."""
    pending = [iter(node.value)]
    while pending:
        pair = next(pending[-1], None)
        if pair is None:
            pending.pop()
            continue
        key, value = pair
        if key.tag != MERGE_TAG:
            yield key, value
            continue
        sources = value.value if isinstance(value, yaml.SequenceNode) else [value]
        for source in reversed([source for source in sources if isinstance(source, yaml.MappingNode)]):
            if len(pending) <= MAX_SETTINGS_DEPTH:
                pending.append(iter(source.value))


def _numeric_scalars(annotation, node, where: str):
    """(the setting's dotted name, scalar node, whether the field is a bool) of every scalar of `node` that a value
    of type `annotation` holds as a number or a boolean: a numeric field, the items of a list of them, the values of
    a mapping of them (a robot config's limits), and the numeric fields of a dataclass (a Union of dataclasses by the
    node's tag, `!Name`, else its first member); a Drake config type's fields as a dataclass's."""
    import types
    import typing
    origin, arguments = typing.get_origin(annotation), typing.get_args(annotation)
    if origin in (typing.Union, types.UnionType):
        members = [member for member in arguments if member is not type(None)]
        tagged = [member for member in members if getattr(node, "tag", "") == f"!{getattr(member, '__name__', '')}"]
        if tagged or members:
            yield from _numeric_scalars((tagged or members)[0], node, where)
    elif origin in (list, tuple) and isinstance(node, yaml.SequenceNode):
        for item in node.value:
            yield from _numeric_scalars(arguments[0] if arguments else None, item, where)
    elif origin in (list, tuple) and isinstance(node, yaml.ScalarNode) and not node.tag.endswith(":null"):
        yield where, node, "list"   # (a single value where the typed load wants a list: its error names no field)
    elif getattr(annotation, "__name__", "") == "ndarray" and isinstance(node, yaml.SequenceNode):
        for item in node.value:   # (a Drake config's array field, Rgba's `rgba`: numbers, nested or not)
            yield from _numeric_scalars(annotation if isinstance(item, yaml.SequenceNode) else float, item, where)
    elif origin is dict and isinstance(node, yaml.MappingNode) and len(arguments) == 2:
        for key, value in _pairs(node):
            yield from _numeric_scalars(arguments[1], value, f"{where}.{getattr(key, 'value', '?')}")
    elif (dataclasses.is_dataclass(annotation) or hasattr(annotation, "__fields__")) and isinstance(node, yaml.MappingNode):
        try:   # (a Drake config type, such as VisualizationConfig, lists its fields in __fields__)
            hints = (typing.get_type_hints(annotation) if dataclasses.is_dataclass(annotation)
                     else {field.name: field.type for field in annotation.__fields__})
        except Exception:   # (a schema whose annotations do not resolve: nothing to check against)
            return
        for key, value in _pairs(node):
            name = getattr(key, "value", None)
            if name in hints:
                yield from _numeric_scalars(hints[name], value, f"{where}.{name}" if where else name)
    elif isinstance(annotation, type) and issubclass(annotation, (int, float)) and isinstance(node, yaml.ScalarNode):
        yield where, node, annotation is bool   # (a bool field's too: `true` or `false`, never text)


# numbers YAML 1.1 reads other than as their decimal digits say: octal (`024` is 20), binary, hexadecimal,
# digits grouped by `_` (`1_00`), base 60 (`1:30` is 90); YAML 1.2's own octal `0o24` (20) under a number tag
YAML11_FORM = re.compile(r"[-+]?(?:0[0-7_]+$|0b|0x|0o)|.*[_:]", re.ASCII | re.IGNORECASE)   # (`0O24` too)


def _form(value: str) -> str:
    digits = value.lstrip("+-")
    if digits.lower().startswith("0o"):
        return "YAML 1.2 octal number"
    return "YAML 1.1 " + ("base-60 number" if ":" in value else "number with digits grouped by '_'" if "_" in value
                          else "binary number" if digits.lower().startswith("0b") else "hexadecimal number"
                          if digits.lower().startswith("0x") else "octal number")


def _quoted_number(node, schema, prefix: str, text: str):
    """(the setting's dotted name, its text, how it is not a number) of the first scalar where `schema` holds a
    number that the file writes as something else YAML reads as text or a boolean: quoted, tagged (`!!str 3`,
    also behind an anchor), or digits of another script (`５`), or None."""
    for where, item, boolean in _numeric_scalars(schema, node, prefix.rstrip(".")):
        written = text[item.start_mark.index:item.end_mark.index]   # (with its anchor and tag, if any)
        tag = next((word for word in written.split() if word.startswith("!")), None)
        if boolean == "list":
            return where, written.strip(), "a single value where a list goes"
        if boolean:   # (`"false"` or `!!str true`: text, which the typed load would read as the boolean)
            if item.style in ("'", '"') or (tag is not None and not item.tag.endswith(":bool")):
                return where, item.value, ("in quotes" if item.style else f"tagged {tag}") + ", not a boolean"
            if item.tag.endswith(":bool") and item.value.lower() not in ("true", "false"):   # (YAML 1.1's `yes`, `on`)
                return where, item.value, "which only YAML 1.1 reads as a boolean"
            continue
        if item.tag in NUMBER_TAGS[:2] and not item.value.isascii():   # (`!!int 0２４`: int() reads any script)
            return where, item.value, f"tagged {tag or item.tag.rsplit(':', 1)[-1]} in digits of another script"
        if item.tag in NUMBER_TAGS[:2] and YAML11_FORM.match(item.value):   # (tagged `!!int 024` too)
            try:   # (as its number tag reads it)
                read = yaml.safe_load(f"!!{item.tag.rsplit(':', 1)[-1]} {item.value}")
            except (ValueError, yaml.YAMLError):
                continue   # (`!!float 0x10`: no number to YAML at all; the typed load's own one-line error)
            return where, item.value, f"which YAML reads as {read!r} (a {_form(item.value)})"
        if tag is None and (item.tag in NUMBER_TAGS or (not item.style and item.tag.endswith(":str") and (
                ASCII_NUMBER.fullmatch(item.value) or not any(character.isnumeric() for character in item.value)))):
            continue   # (`1e-4`: text to PyYAML, a number to the typed load; `many`: the typed load's own error)
        if item.style in ("'", '"'):
            return where, item.value, "in quotes"
        if tag is not None and item.tag not in NUMBER_TAGS[:2]:
            return where, item.value, f"tagged {tag}"
        if tag is not None:
            continue   # (`!!float 3`)
        return where, item.value, f"read by YAML as {'a boolean' if item.tag.endswith(':bool') else 'text'}"
    return None


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


def read_yaml_document(path):
    """A YAML file's document as plain Python values, tags ignored (to see its layout before the typed
    load); None when it cannot be read or parsed, is no regular file (a FIFO: reading would block) or is
    larger or deeper than any settings file (MAX_SETTINGS_BYTES, MAX_SETTINGS_DEPTH); the typed load then says why."""
    if not pathlib.Path(path).is_file() or pathlib.Path(path).stat().st_size > MAX_SETTINGS_BYTES:
        return None
    try:
        text = pathlib.Path(path).read_text()
        return yaml.load(text, Loader=_TagsAsPlainValues) if not nested_too_deep(text) else None
    except (OSError, UnicodeDecodeError, yaml.YAMLError, ValueError):   # (ValueError: `!!float 0x10`, no float)
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
