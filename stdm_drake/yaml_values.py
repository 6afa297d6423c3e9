"""A settings file's values read against its schema before Drake's typed load (`config.load_yaml_config`), where the
typed load would read them otherwise or fail without naming the setting: a number or boolean written as text (quoted,
tagged, another script's digits, a YAML 1.1 form), a key stated twice in one mapping, a value of another shape than
the setting (a single value, null or a mapping where a list goes; a list where a number goes)."""
import dataclasses
import math
import pathlib
import re

import yaml

from stdm_drake.errors import InputError
from stdm_drake.files import line_text

# libyaml's parser where PyYAML was built with it (the wheels are) for composing and loading: a settings file of
# 300 kB took 44 s to refuse through the pure-Python parser, 5 s now (most of it Drake's typed load). libyaml gives
# a plain scalar the style "" (not None). The nesting scan stays pure Python: it stops at the first level too deep,
# where libyaml's scanner reads ahead and fails at its own limit of 1,000 levels first.
YAML_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)

# Nesting levels of mappings and lists a settings file may hold (the deepest schema nests 4: an optimizer's
# settings in the MPC's); past it the YAML parsers recurse once per level (a 2,000-deep list: a RecursionError).
MAX_SETTINGS_DEPTH = 64


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
            raise InputError(f"{path}: {where} is {line_text(_shortened(value))}, {how}; write it as a list ([x]; a "
                             "per-joint setting takes one value x for every joint that way)")
        if "where a whole number goes" in how:   # (`_whole_number`'s)
            raise InputError(f"{path}: {where} is written {how}")
        if how.endswith(" goes"):
            raise InputError(f"{path}: {where} is {line_text(_shortened(value))}, {how}; leave the setting out for its "
                             "default, or write it in that form")
        if how.endswith("under its tag !!int"):   # (`!!int 20.0`)
            raise InputError(f"{path}: {where} is written {value or repr(value)}, {how}; write a whole number, or leave "
                             "out the tag")
        if how.startswith(("which YAML reads as", "which YAML cannot read")):
            raise InputError(f"{path}: {where} is written {value or repr(value)}, {how}; write the number in plain "
                             "decimal digits")
        if how == "which only YAML 1.1 reads as a boolean":
            raise InputError(f"{path}: {where} is written {value}, {how}; write true or false")
        if how.endswith(", not a boolean"):
            raise InputError(f"{path}: {where} is {value!r} {how}; write true or false without quotes or a tag")
        fix = "in ASCII digits" if how.endswith("another script") else {
            "in quotes": "without quotes", "read by YAML as text": "in ASCII digits"}.get(
            how, "without the tag" if how.startswith("tagged") else "in digits")
        raise InputError(f"{path}: {where} is {value!r} {how}, not a number; write the number {fix}")


def _shortened(value: str, width: int = 80) -> str:
    """`value` cut to `width` characters, "..." marking a cut."""
    return value if len(value) <= width else value[:width - 3] + "..."


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
        if getattr(node, "tag", "").endswith(":null") and type(None) in arguments:
            return   # (None is one of the field's values)
        members = [member for member in arguments if member is not type(None)]
        if str in members and isinstance(node, yaml.ScalarNode) and node.tag.endswith(":str"):
            return   # (text is one of the field's values: `jacobian_refresh: "all"`)
        tagged = [member for member in members if getattr(node, "tag", "") == f"!{getattr(member, '__name__', '')}"]
        shaped = [member for member in members if _shape(member) == _shape(node)]   # (`float | list[float]`)
        if tagged or shaped or members:
            yield from _numeric_scalars((tagged or shaped or members)[0], node, where)
    elif origin in (list, tuple) and isinstance(node, yaml.SequenceNode):
        for item in node.value:
            yield from _numeric_scalars(arguments[0] if arguments else None, item, where)
    elif origin in (list, tuple) or (origin is dict and not isinstance(node, yaml.MappingNode)):
        # (a value of another shape than the typed load wants: its error names no field)
        yield where, node, "a list" if origin in (list, tuple) else "a mapping"
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
    elif (dataclasses.is_dataclass(annotation) or hasattr(annotation, "__fields__")) and where and node is not None \
            and not (isinstance(node, yaml.ScalarNode) and node.tag.startswith("!") and not node.value):
        yield where, node, "a mapping"   # (null, a single value or a list where settings go; `!Rti` alone is empty)
    elif isinstance(annotation, type) and issubclass(annotation, (int, float)) and isinstance(node, yaml.ScalarNode):
        # (a bool field's too: `true` or `false`, never text; an int field's marked: a whole number goes there)
        yield where, node, True if annotation is bool else WHOLE if issubclass(annotation, int) else False
    elif isinstance(annotation, type) and issubclass(annotation, (int, float)) and node is not None:
        yield where, node, "a number"   # (a list or a mapping where a number goes)


def _shape(value) -> str:
    """"list", "mapping" or "scalar": of a YAML node, or of the values of a type."""
    import typing
    if isinstance(value, yaml.Node):
        return ("list" if isinstance(value, yaml.SequenceNode) else "mapping" if isinstance(value, yaml.MappingNode)
                else "scalar")
    origin = typing.get_origin(value)
    if origin in (list, tuple) or getattr(value, "__name__", "") == "ndarray":
        return "list"
    return "mapping" if origin is dict or dataclasses.is_dataclass(value) or hasattr(value, "__fields__") else "scalar"


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


WHOLE = "a whole number"   # (`_numeric_scalars`' mark of an int field's scalar)


def _whole_number(item, tag: str | None) -> str | None:
    """How an int field's plain or number-tagged (`tag`) scalar `item` is no whole number the typed load reads, or
    None: a fraction (`0.5`, which the typed load's error would name `'_'` in a list), infinite or not a number, or
    untagged in an exponent form YAML 1.1 reads as text (`2e1`: 20.0 to YAML 1.2; the typed load cannot read it)."""
    if not ASCII_NUMBER.fullmatch(item.value):
        return None
    try:
        number = yaml.safe_load(f"!!float {item.value}")
    except (ValueError, yaml.YAMLError):
        return None
    if not math.isfinite(number) or number != int(number):
        return f"{item.value}, not a whole number, where a whole number goes"
    if tag is None and item.tag.endswith(":str") and "e" in item.value.lower():   # (`1.0e+1`: 10.0 to every YAML)
        return f"{item.value}, a number in exponent form (text to YAML 1.1, {number!r} to YAML 1.2), where a whole " \
               f"number goes: write {int(number)}"
    return None


def _quoted_number(node, schema, prefix: str, text: str):
    """(the setting's dotted name, its text, how it is not a number) of the first scalar where `schema` holds a
    number that the file writes as something else YAML reads as text or a boolean: quoted, tagged (`!!str 3`,
    also behind an anchor), or digits of another script (`５`), or None."""
    for where, item, boolean in _numeric_scalars(schema, node, prefix.rstrip(".")):
        written = text[item.start_mark.index:item.end_mark.index]   # (with its anchor and tag, if any)
        tag = next((word for word in written.split() if word.startswith("!")), None)
        if boolean in ("a list", "a mapping", "a number"):
            shape = "null" if item.tag.endswith(":null") else {"list": "a list", "mapping": "a mapping"}.get(
                _shape(item), "a single value")
            return where, written.strip(), f"{shape} where {boolean} goes"
        whole, boolean = boolean == WHOLE, boolean is True
        if whole and not item.style and (tag is None or item.tag in NUMBER_TAGS[:2]) and _whole_number(item, tag):
            return where, item.value, _whole_number(item, tag)
        if boolean:   # (`"false"` or `!!str true`: text, which the typed load would read as the boolean)
            if item.style in ("'", '"') or (tag is not None and not item.tag.endswith(":bool")):
                return where, item.value, ("in quotes" if item.style else f"tagged {tag}") + ", not a boolean"
            if item.tag.endswith(":bool") and item.value.lower() not in ("true", "false"):   # (YAML 1.1's `yes`, `on`)
                return where, item.value, "which only YAML 1.1 reads as a boolean"
            continue
        if item.tag in NUMBER_TAGS[:2] and not item.value.isascii():   # (`!!int 0２４`: int() reads any script)
            return where, item.value, f"tagged {tag or item.tag.rsplit(':', 1)[-1]} in digits of another script"
        if item.tag in NUMBER_TAGS[:2] and (tag is not None or YAML11_FORM.match(item.value)):
            kind = item.tag.rsplit(":", 1)[-1]
            form = f" (a {_form(item.value)})" if YAML11_FORM.match(item.value) else ""
            try:   # (as its number tag reads it; tagged `!!int 024` too)
                read = yaml.safe_load(f"!!{kind} {item.value}")
            except (ValueError, IndexError, yaml.YAMLError):   # (`!!float 0x10`, `!!int 20.0`, `!!int ""`)
                return where, item.value, f"which YAML cannot read under its tag !!{kind}{form}"
            alike = ASCII_NUMBER.fullmatch(item.value) and (kind == "float" or read == int(item.value, 10))
            if form and not alike:   # (`!!float 01`: 1.0 to all; `05` and `!!int 05`: 5 to all, `010` 8 or 10)
                return where, item.value, f"which YAML reads as {read!r}{form}"
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


def boolean_words_as_text(path, schema) -> str | None:
    """The text of settings file `path` with every choice of a text setting that YAML 1.1 reads as a boolean quoted
    (`per_group: on`, where the setting's choices are "on" and "off": the flag's own words, which YAML 1.1 reads as
    True), so that the typed load reads the words as written; None where there is none (or the file does not parse:
    the typed load says why). InputError (one line naming the setting and its choices) for a boolean there that is
    no choice as written (`Off`, `No`, `!!bool off`). The settings are `schema`'s dataclass fields with `choices` in their metadata
    (`learning.settings.setting`), nested dataclasses followed."""
    try:
        text = pathlib.Path(path).read_text(encoding="utf-8-sig")
        node = yaml.compose(text, Loader=YAML_LOADER)
    except (yaml.YAMLError, OSError, UnicodeDecodeError, RecursionError):
        return None
    found = list(_boolean_choices(schema, node))
    for start, end, word, name, choices in found:
        if text[start:end] != word or word not in choices:   # (`!!bool on`, `Off`, `No`: a boolean, no choice)
            raise InputError(f"{path}: {name} is written {text[start:end]}, which YAML 1.1 reads as a boolean; write "
                             f"one of {', '.join(choices)}")
    spans = sorted((start, end, word) for start, end, word, _, _ in found)
    spans.reverse()
    for start, end, value in spans:
        text = text[:start] + f'"{value}"' + text[end:]
    return text if spans else None


def _boolean_choices(schema, node):
    """(start, end, word, field name, choices) of every plain scalar of mapping `node` that YAML 1.1 reads as a
    boolean where `schema`'s field takes text among its choices."""
    import typing
    if not dataclasses.is_dataclass(schema) or not isinstance(node, yaml.MappingNode):
        return
    try:
        hints = typing.get_type_hints(schema)
    except Exception:   # (annotations that do not resolve: nothing to read against)
        return
    fields = {field.name: field for field in dataclasses.fields(schema)}
    for key, value in _pairs(node):
        field = fields.get(getattr(key, "value", None))
        if field is None:
            continue
        kind = hints.get(field.name)
        members = [member for member in typing.get_args(kind) if member is not type(None)] or [kind]
        if dataclasses.is_dataclass(members[0]):
            yield from _boolean_choices(members[0], value)
            continue
        choices = field.metadata.get("choices") or ()
        if str in members and choices and isinstance(value, yaml.ScalarNode) and not value.style \
                and value.tag.endswith(":bool"):
            yield value.start_mark.index, value.end_mark.index, value.value, field.name, tuple(choices)
