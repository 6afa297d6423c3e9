"""The first reading of a robot's XML files (URDF, SDF, SRDF), before any parser that recurses or expands: the
checks that make the toolbox's reading and Drake's (or MoveIt's) the same file, and the size a description may
have. Used by `robots.description` (and the SRDF readers)."""
from __future__ import annotations

import math
import pathlib
import re
import sys

from stdm_drake.errors import InputError
from stdm_drake.robots import xml_readings


class WrongCount(ValueError):
    """An element the description states more often than its format allows, or with the wrong count of values."""


class UnreadNumber(ValueError):
    """A value the checks read that is not written as a number (`description.PLAIN_NUMBER`)."""

# Links, joints and frames one description may state. A robot has tens to a few hundred (a humanoid about 100, a
# mobile manipulator with its hand about 200); every command reads, checks and builds each of them several times
# (about 1.2 ms apiece here: `robot init` took 24 s for 20,000 frames), so beyond this a file is work, not a robot.
MAX_FRAMES = 10_000
FRAME_TAGS = ("link", "joint", "frame")
# SDF <frame>s cost more, and more than in proportion (`robot init` of an arm with a chain of 1,000 frames, each
# attached to the one before: 13 s; 2,000: 50 s); an arm's SDF states tens
MAX_SDF_FRAMES = 1_000
# A description's size in bytes: the shipped ones are 10-20 kB and the 1,119 files of the robot corpus at most 34 kB
# (meshes are files of their own); every command reads a description several times (8 MB: 42 s in `robot check`)
MAX_DESCRIPTION_BYTES = 4 << 20
# What a number's text may be padded with: XML's white space. Not Unicode's (str.strip()): a no-break space after a
# number stays in the message, where it shows as \xa0 instead of an invisible fault
ASCII_SPACE = " \t\r\n"
MAX_DEPTH = 64   # elements nested in each other (a URDF nests 5 deep, an SDF of nested models about 10)
# The numbers a description states that Drake reads, and so the toolbox's number rule checks (`check_numbers`): URDF
# attributes, SDF elements whose text is numbers (an SDF <friction> with child elements is a surface's, not these)
NUMBER_ATTRIBUTES = {"xyz", "rpy", "lower", "upper", "effort", "velocity", "damping", "friction", "ixx", "ixy", "ixz",
                     "iyy", "iyz", "izz", "multiplier", "offset", "size", "radius", "length", "scale",
                     "soft_lower_limit", "soft_upper_limit", "k_position", "k_velocity", "rising", "falling",
                     "drake:acceleration", "rgba"}
NUMBER_ELEMENTS = {"pose", "xyz", "lower", "upper", "effort", "velocity", "damping", "friction", "spring_reference",
                   "spring_stiffness", "mass", "ixx", "ixy", "ixz", "iyy", "iyz", "izz", "radius", "length", "size",
                   "scale", "stiffness", "dissipation", "ambient", "diffuse", "specular", "emissive"}   # (colours:
# visual only, but Drake reads `1junk` as 1 and SDFormat refuses digits of another script in lines of its own)


# Attributes one element may carry: a URDF or SDF element has at most a handful (an <inertia> six); 200,000 on one
# element made a 3 MB file that `robot init` worked on for minutes
MAX_ATTRIBUTES = 100
# The values an SDF element's text holds (SDFormat reads others with several lines of its own): a joint axis x y z
# (a <size> is a box's 3 or a plane's 2: not counted); a pose x y z roll pitch yaw, or x y z and a quaternion with
# rotation_format="quat_xyzw"; both finite
SDF_VALUE_COUNTS = {"xyz": (3,)}
POSE_VALUE_COUNTS = {"euler_rpy": (6,), "quat_xyzw": (7,)}   # by the <pose>'s rotation_format


def check_xml(path: pathlib.Path, kind: str, count_frames: bool = False) -> None:
    """InputError (one line) for an XML file the toolbox cannot read as Drake (or MoveIt) would: not well-formed
    (an undefined entity included), declaring entities (Python's parser expands them, Drake's does not; a "billion
    laughs" file among them), nested more than MAX_DEPTH deep or with an element of more than MAX_ATTRIBUTES
    attributes, or larger than MAX_DESCRIPTION_BYTES. kind: what the file should be, for the message ("a URDF or SDF
    file is"). count_frames (a description): also refuse one of more than MAX_FRAMES links, joints and frames or
    MAX_SDF_FRAMES <frame>s. One pass, stopped at the first past a budget, before anything else reads it."""
    from xml.parsers import expat

    def declared(name, *_):   # (raised at the declaration: nothing is expanded)
        raise InputError(f"{path.name} declares the XML entity {name!r}; Drake's parser does not expand entities, "
                         "so write their text out in the file")

    frames = sdf_frames = depth = 0
    # per open element: [tag, line, its nodes [kind, [pieces of text]] until it has a child element (then None)]
    # (`split_text`); whether in a CDATA section, and whether the next text starts a node (after a comment, ...)
    open_elements, state = [], dict(cdata=False, new=True)

    def node(kind: str, text: str = "", new: bool = True) -> None:
        nodes = open_elements[-1][2] if open_elements else None
        if nodes is None:
            return
        if kind in ("text", "cdata") and not state["new"] and nodes and nodes[-1][0] == kind:
            nodes[-1][1].append(text)
        else:
            nodes.append([kind, [text]])
        state["new"] = new

    def ended(_tag):
        nonlocal depth
        depth -= 1
        tag, line, nodes = open_elements.pop()
        state["new"] = True
        if nodes and any(kind != "text" for kind, _ in nodes):
            xml_readings.split_text(path, tag, line, [(kind, "".join(pieces)) for kind, pieces in nodes])

    def started(tag, attributes):
        nonlocal frames, sdf_frames, depth
        depth += 1
        if open_elements:
            open_elements[-1][2] = None
        line = checker.CurrentLineNumber + skipped
        open_elements.append([tag, line, []])
        state["new"] = True
        if len(attributes) > MAX_ATTRIBUTES:
            raise InputError(f"{path.name}: an element <{tag}> carries {len(attributes):,} attributes (line "
                             f"{line}); a description's elements carry a handful, at most "
                             f"{MAX_ATTRIBUTES} are read")
        if depth > MAX_DEPTH:
            raise InputError(f"{path.name} nests elements more than {MAX_DEPTH} deep (line {line}); "
                             "a robot description nests 5 to 10 (SDF models inside models: a few)")
        if count_frames and tag in FRAME_TAGS:
            frames += 1
            sdf_frames += tag == "frame"
            if sdf_frames > MAX_SDF_FRAMES:
                raise InputError(f"{path.name} states more than {MAX_SDF_FRAMES:,} <frame>s (line "
                                 f"{line}); an arm states tens, and the work grows "
                                 "faster than their count (2,000 in a chain: 50 s); keep in the file what the robot "
                                 "is made of")
            if frames > MAX_FRAMES:
                raise InputError(f"{path.name} states more than {MAX_FRAMES:,} links, joints and frames (line "
                                 f"{line}); a robot has tens to hundreds, and every command reads "
                                 "and builds each of them several times (about 1.2 ms each); keep in the file what "
                                 "the robot is made of")

    if pathlib.Path(path).stat().st_size > MAX_DESCRIPTION_BYTES:   # (an SRDF too: 100,000 pairs, 8 MB, took 12 s)
        raise InputError(f"{path.name} is {pathlib.Path(path).stat().st_size / 2**20:.1f} MiB, more than the "
                         f"{MAX_DESCRIPTION_BYTES >> 20} MiB a robot description or SRDF here may be (they are kilobytes, "
                         "with meshes in files of their own); every command reads it several times")
    data, skipped = _text(path)
    checker = expat.ParserCreate()
    checker.buffer_text = True   # (a text's lines in one call)
    checker.EntityDeclHandler = declared
    checker.StartElementHandler, checker.EndElementHandler = started, ended
    checker.CharacterDataHandler = lambda text: node("cdata" if state["cdata"] else "text", text, new=False)
    checker.CommentHandler = lambda _text: node("comment")
    checker.ProcessingInstructionHandler = lambda _target, _data: node("instruction")
    checker.StartCdataSectionHandler = lambda: (state.update(cdata=True), node("cdata", new=False))
    checker.EndCdataSectionHandler = lambda: state.update(cdata=False, new=True)
    try:
        checker.Parse(data, True)
    except expat.ExpatError as error:
        raise InputError(f"{path.name} is not well-formed XML ({expat.ErrorString(error.code)}: line "
                         f"{error.lineno + skipped}, column {error.offset}); {kind}") from None


def _text(path: pathlib.Path) -> tuple[bytes, int]:
    """(the file's bytes from its first one that is not white space, the lines skipped): Drake's XML parser
    (TinyXML2) and MoveIt's read past blank lines before the `<?xml ...?>` declaration, which Python's (expat)
    refuses (pybullet's biped2d_pybullet.urdf has three)."""
    data = pathlib.Path(path).read_bytes()
    start = len(data) - len(data.lstrip(b" \t\r\n"))
    return data[start:], data[:start].count(b"\n")


def parse(path: pathlib.Path):
    """The file's ElementTree, read as Drake's parser reads it (`_text`): without XML namespaces, as TinyXML2 reads a
    file, so that a tag keeps its prefix as written (`drake:rotor_inertia`, which Drake's parser looks for by that
    name) and a prefix no `xmlns:` declares is read too (Python's namespace-aware parser refused one with a
    traceback). ElementTree.ParseError where the file is not well-formed."""
    import xml.etree.ElementTree as ElementTree
    from xml.parsers import expat
    builder = ElementTree.TreeBuilder()
    parser = expat.ParserCreate()   # (no namespace_separator: names as written)
    parser.buffer_text = True
    parser.StartElementHandler = builder.start
    parser.EndElementHandler = builder.end
    parser.CharacterDataHandler = builder.data
    try:
        parser.Parse(_text(path)[0], True)
    except expat.ExpatError as error:
        raised = ElementTree.ParseError(f"{expat.ErrorString(error.code)}: line {error.lineno}, column {error.offset}")
        raised.code, raised.position = error.code, (error.lineno, error.offset)
        raise raised from None
    return ElementTree.ElementTree(builder.close())


def check_numbers(root, rule) -> None:
    """UnreadNumber naming the element and its link, joint or model, for a number the description states
    (NUMBER_ATTRIBUTES of URDF elements, <mass value>, the text of SDF's NUMBER_ELEMENTS) that is not written as
    `rule` (a compiled pattern: plain ASCII decimals) reads numbers: Drake reads `8junk` as 8 and `-0x1p3` as -0,
    where the toolbox would read otherwise or not at all. Walked without recursion (a file may nest deeply)."""
    sdf = root.tag == "sdf"
    materials = {} if sdf else xml_readings.first_materials(root)
    pending = [(root, "the file")]
    while pending:
        element, owner = pending.pop()
        name = element.get("name")
        if element.tag in ("link", "joint", "model", "frame", "transmission") and name is not None:   # (a URDF
            # transmission holds Drake's rotor inertia and gear ratio: held-out run 39 read "the file: its <drake:...>")
            owner = f"{element.tag} {name!r}"
        if element.tag == "geometry":
            _check_shapes(element, owner, sdf)
        if element.tag.startswith("drake:"):
            _check_drake_value(element, owner, rule, sdf)
        if element.tag in ("mimic", "drake:mimic"):
            _check_mimic(element, owner, rule)
        for tag in (xml_readings.SDF_SAME_CHILDREN if sdf else xml_readings.URDF_SAME_CHILDREN).get(element.tag, ()):
            children = [child for child in element if child.tag in xml_readings.SHAPES] if tag == "*" else \
                element.findall(tag)
            if xml_readings.differ(children, sdf, materials):
                itself = "it" if element.tag in ("link", "joint", "model") else f"its <{element.tag}>"
                what = (f"{len(children)} shapes ({', '.join(f'<{child.tag}>' for child in children)})" if tag == "*"
                        else f"{len(children)} <{tag}> elements")
                raise WrongCount(f"{owner}: {itself} states {what} that differ; {'SDF' if sdf else 'URDF'} gives one "
                                 "(Drake's parser reads the first and ignores the others): keep the one meant")
        if sdf:
            if element.tag == "dynamics":
                _check_joint_dynamics({child.tag: child.text for child in element}, owner)
            if element.tag in NUMBER_ELEMENTS and len(element) == 0 and element.text is not None:
                _numbers(element.text, rule, f"{owner}: its <{element.tag}>", UnreadNumber)
                _check_subnormal(element.text, f"{owner}: its <{element.tag}>")
                counts, form = SDF_VALUE_COUNTS.get(element.tag, ()), ""
                if element.tag == "pose":   # (other rotation formats: SDFormat's own error)
                    rotation = element.get("rotation_format", "euler_rpy")
                    counts, form = POSE_VALUE_COUNTS.get(rotation, ()), f" for rotation_format {rotation}"
                    if rotation == "quat_xyzw" and element.get("degrees", "").strip(ASCII_SPACE) in ("true", "1"):
                        raise WrongCount(f"{owner}: its <pose> states degrees true with rotation_format quat_xyzw, "
                                         "which SDFormat refuses (a quaternion holds no angles): leave degrees out")
                values = ascii_words(element.text)
                if counts and len(values) not in counts:
                    raise WrongCount(f"{owner}: its <{element.tag}> holds {len(values)} values, SDFormat reads "
                                     f"{' or '.join(map(str, counts))}{form}")
                if element.tag in ("pose", "xyz") and not all(math.isfinite(float(value)) for value in values):
                    raise WrongCount(f"{owner}: its <{element.tag}> is {element.text.strip(ASCII_SPACE)!r}; a "
                                     f"{'pose' if element.tag == 'pose' else 'direction'} is finite numbers")
                if element.tag == "pose":
                    _check_offset(values[:3], f"{owner}: its <pose>")
        else:
            if element.tag == "dynamics":
                _check_joint_dynamics(dict(element.attrib), owner)
            for attribute, text in element.attrib.items():
                if attribute in NUMBER_ATTRIBUTES or (element.tag == "mass" and attribute == "value"):
                    _numbers(text, rule, f"{owner}: its <{element.tag}> {attribute}", UnreadNumber)
            if element.tag == "origin" and element.get("xyz") is not None:
                _check_offset(ascii_words(element.get("xyz")), f"{owner}: its <origin> xyz")
            acceleration = element.get("drake:acceleration") if element.tag == "limit" else None
            if acceleration is not None and not 0 <= float(acceleration) < math.inf:   # (Drake asserts on < 0)
                raise WrongCount(f"{owner}: its <limit> drake:acceleration is {acceleration.strip(ASCII_SPACE)!r}; an "
                                 "acceleration limit is a finite number >= 0 (rad/s² or m/s²)")
        pending += [(child, owner) for child in element]


# A joint's <dynamics> (URDF's attributes, SDF's elements): what Drake's joints and springs assert on (a negative
# spring stiffness ended `robot init` with Drake's assertion text, exit 1; an infinite spring reference in the
# simulator's traceback), and magnitudes beyond any robot's joint (a damping of 1e300 froze the joint without a word;
# the plant effects' own bound, effects.EFFECT_BOUNDS: 1e6; a spring reference as far as a frame's offset, MAX_OFFSET):
# (the lowest value, the highest, its unit)
JOINT_DYNAMICS = {"damping": (0.0, 1e6, "N m s/rad or N s/m"), "friction": (0.0, 1e6, "N m or N"),
                  "spring_stiffness": (0.0, 1e8, "N m/rad or N/m"), "spring_reference": (-1e6, 1e6, "rad or m")}


def _check_joint_dynamics(texts: dict, owner: str) -> None:
    """WrongCount for a <dynamics> value (texts: its name -> text, as the file writes it) outside JOINT_DYNAMICS."""
    for key, text in texts.items():
        words = ascii_words(text or "")
        try:
            value = float(words[0]) if key in JOINT_DYNAMICS and len(words) == 1 else None
        except ValueError:
            continue   # (the number check says why)
        if value is None:
            continue
        low, high, unit = JOINT_DYNAMICS[key]
        if not (math.isfinite(value) and low <= value <= high):
            raise WrongCount(f"{owner}: its <dynamics> {key} is {value:g}; a joint's is in [{low:g}, {high:g}] {unit}")


# A frame's offset from its parent, m: a robot's are centimetres to metres; one of 1e300 m made the plant's mass
# matrix overflow ("Eigenvalues did not converge" as the only line)
MAX_OFFSET = 1e6


def _check_offset(words: list, what: str) -> None:
    try:
        values = [float(word) for word in words]
    except ValueError:
        return   # (the number check says why)
    if not all(math.isfinite(value) for value in values):
        raise WrongCount(f"{what} is {' '.join(words)!r}; a frame's offset is finite (m)")
    if any(abs(value) > MAX_OFFSET for value in values):
        raise WrongCount(f"{what} places a frame {max(map(abs, values)):g} m from its parent; a robot's frames lie "
                         f"within {MAX_OFFSET:g} m of each other")


# A visual's or collision's shape: its dimensions (m) as Drake's shape constructors assert on them (a negative
# cylinder radius or a box of size 0 ended `robot init` and `collect` with Drake's assertion text, exit 1; SDFormat
# replaces a sphere radius of 0 or less by 1 m with a warning): finite, at least MIN_LENGTH (a URDF sphere's radius
# may be 0, a point), and within MAX_OFFSET. URDF: attributes (Drake's <drake:capsule> and <drake:ellipsoid> too); SDF:
# child elements.
MIN_LENGTH = 1e-6   # m: a micrometre, far below any part of a robot (a side of 1e-300 m has a volume of 0 in doubles)
SHAPE_DIMENSIONS = {"box": ("size",), "cylinder": ("radius", "length"), "capsule": ("radius", "length"),
                    "sphere": ("radius",), "ellipsoid": ("a", "b", "c", "radii")}
# an SDF shape's dimensions that SDFormat fills with a default (1 m) where the file leaves them out
SDF_DIMENSIONS = {"box": ("size",), "cylinder": ("radius", "length"), "capsule": ("radius", "length"),
                  "sphere": ("radius",), "ellipsoid": ("radii",)}


def _check_shapes(geometry, owner: str, sdf: bool) -> None:
    """WrongCount for a shape of the <geometry> element whose dimensions SHAPE_DIMENSIONS refuses."""
    for shape in geometry:
        kind = shape.tag.rsplit(":", 1)[-1]   # (`drake:capsule` too: names as written, `parse`)
        for name in SHAPE_DIMENSIONS.get(kind, ()):
            if sdf:
                found = next((child for child in shape if child.tag == name), None)
                text = None if found is None else found.text
                if name in SDF_DIMENSIONS.get(kind, ()) and not ascii_words(text or ""):
                    raise WrongCount(f"{owner}: its <{kind}> gives no <{name}>; SDFormat would read its default, 1 m "
                                     "(give it in m)")
            else:
                text = shape.get(name)
            try:
                values = [float(word) for word in ascii_words(text or "")]
            except ValueError:
                continue   # (the number check says why)
            if kind == "box" and len(values) != 3:   # (SDFormat's error for 2 came in several lines of its own)
                raise WrongCount(f"{owner}: its <box> size holds {len(values)} values; a box's size is 3 (x y z in m)")
            zero = kind == "sphere" and not sdf   # (a URDF sphere of radius 0 is a point to Drake; SDFormat makes it 1 m)
            if not all(math.isfinite(value) and (MIN_LENGTH <= value <= MAX_OFFSET or (zero and value == 0))
                       for value in values):
                bound = f"0 or at least {MIN_LENGTH:g} m" if zero else f"at least {MIN_LENGTH:g} m"
                raise WrongCount(f"{owner}: its <{kind}> {name} is {(text or '').strip(ASCII_SPACE)!r}; a shape's "
                                 f"dimensions are finite, {bound} and at most {MAX_OFFSET:g} m")


def _check_subnormal(text: str, what: str) -> None:
    """WrongCount for a number SDFormat cannot read: a magnitude below the smallest normal double (2.2e-308, not 0),
    which its parser calls "Out of range" in several lines (a URDF's is read, as 0 or nearly)."""
    for word in ascii_words(text):
        try:
            value = abs(float(word))
        except ValueError:
            return   # (the number check says why)
        if 0 < value < sys.float_info.min:
            raise WrongCount(f"{what} holds {word}; SDFormat reads numbers of magnitude 0 or at least "
                             f"{sys.float_info.min:.3g}")


# Drake's own elements (its URDF and SDF extensions, `drake:NAME`) whose one value Drake's parser reads as a number
# and puts in the plant without a check of its own (a negative rotor inertia, a gear ratio of 1e300 or `0x1p3` were
# accepted): (the lowest value, the highest, its unit); the bounds as the plant effects' (effects.EFFECT_BOUNDS)
DRAKE_VALUES = {"rotor_inertia": (0.0, 1e3, "kg m²"), "gear_ratio": (1e-6, 1e5, ""),   # (1e-320: no gear at all)
                "mu_dynamic": (0.0, 1e3, ""), "mu_static": (0.0, 1e3, ""),
                "hydroelastic_modulus": (math.ulp(0.0), 1e15, "Pa"), "hunt_crossley_dissipation": (0.0, 1e6, "s/m"),
                "relaxation_time": (0.0, 1e6, "s"), "mesh_resolution_hint": (MIN_LENGTH, 1e6, "m"),
                "point_contact_stiffness": (0.0, 1e15, "N/m"), "acceleration": (0.0, 1e300, "rad/s² or m/s²")}


def _check_drake_value(element, owner: str, rule, sdf: bool) -> None:
    """UnreadNumber or WrongCount for a `drake:NAME` element of DRAKE_VALUES whose value (URDF: its `value`
    attribute; SDF: its text) is not a plain number or lies outside its bounds."""
    name = element.tag.split(":", 1)[1]
    text = element.text if sdf else element.get("value")
    if name not in DRAKE_VALUES or text is None or (sdf and len(element)):
        return
    what = f"{owner}: its <{element.tag}>"
    _numbers(text, rule, what, UnreadNumber)
    if sdf:
        _check_subnormal(text, what)
    words = ascii_words(text)
    low, high, unit = DRAKE_VALUES[name]
    if len(words) == 1 and not (low <= float(words[0]) <= high):   # (NaN too)
        bounds = f"(0, {high:g}]" if low == math.ulp(0.0) else f"[{low:g}, {high:g}]"
        raise WrongCount(f"{what} is {words[0]}; Drake's {name} is in {bounds}{' ' + unit if unit else ''}")


MAX_MIMIC_MULTIPLIER = 1e5   # a coupled joint's ratio to its leader, as a gear ratio (1e300 overflows the coupler)


def _check_mimic(element, owner: str, rule) -> None:
    """UnreadNumber or WrongCount for a joint coupling (URDF <mimic>, Drake's SDF <drake:mimic>) whose multiplier or
    offset is not a plain number, or whose multiplier's magnitude is above MAX_MIMIC_MULTIPLIER or offset above
    MAX_OFFSET."""
    for name, bound in (("multiplier", MAX_MIMIC_MULTIPLIER), ("offset", MAX_OFFSET)):
        text = element.get(name)
        if text is None:
            continue
        what = f"{owner}: its <{element.tag}> {name}"
        _numbers(text, rule, what, UnreadNumber)
        words = ascii_words(text)
        if len(words) != 1 or not abs(float(words[0])) <= bound:   # (NaN too)
            raise WrongCount(f"{what} is {text.strip(ASCII_SPACE)!r}; a joint coupling's {name} is one number of "
                             f"magnitude at most {bound:g}")


def ascii_words(text: str) -> list[str]:
    """`text` split at ASCII white space, as TinyXML2 and SDFormat split a list of numbers (a no-break space is
    none: `0\xa00` is one word, which no number rule reads)."""
    return [word for word in re.split(f"[{ASCII_SPACE}]+", text) if word]


def _numbers(text: str, rule, what: str, error) -> None:
    if not all(rule.fullmatch(part) for part in ascii_words(text)):
        raise error(f"{what} is {text.strip(ASCII_SPACE)!r}")
