"""The first reading of a robot's XML files (URDF, SDF, SRDF), before any parser that recurses or expands: the
checks that make the toolbox's reading and Drake's (or MoveIt's) the same file, and the size a description may
have. Used by `robots.description` (and the SRDF readers)."""
from __future__ import annotations

import pathlib

from stdm_drake.errors import InputError

# Links, joints and frames one description may state. A robot has tens to a few hundred (a humanoid about 100, a
# mobile manipulator with its hand about 200); every command reads, checks and builds each of them several times
# (about 1.2 ms apiece here: `robot init` took 24 s for 20,000 frames), so beyond this a file is work, not a robot.
MAX_FRAMES = 10_000
FRAME_TAGS = ("link", "joint", "frame")


def check_xml(path: pathlib.Path, kind: str, count_frames: bool = False) -> None:
    """InputError (one line) for an XML file the toolbox cannot read as Drake (or MoveIt) would: not well-formed
    (an undefined entity included), or declaring entities (Python's parser expands them, Drake's does not; a
    "billion laughs" file among them). kind: what the file should be, for the message ("a URDF or SDF file is").
    count_frames: also refuse a description of more than MAX_FRAMES links, joints and frames, in this one pass
    (stopped at the first past the budget), before anything else reads it."""
    from xml.parsers import expat

    def declared(name, *_):   # (raised at the declaration: nothing is expanded)
        raise InputError(f"{path.name} declares the XML entity {name!r}; Drake's parser does not expand entities, "
                         "so write their text out in the file")

    frames = 0

    def started(tag, _attributes):
        nonlocal frames
        if tag in FRAME_TAGS:
            frames += 1
            if frames > MAX_FRAMES:
                raise InputError(f"{path.name} states more than {MAX_FRAMES:,} links, joints and frames (line "
                                 f"{checker.CurrentLineNumber}); a robot has tens to hundreds, and every command reads "
                                 "and builds each of them several times (about 1.2 ms each); keep in the file what "
                                 "the robot is made of")

    checker = expat.ParserCreate()
    checker.EntityDeclHandler = declared
    if count_frames:
        checker.StartElementHandler = started
    data, skipped = _text(path)
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
    """The file's ElementTree, read as Drake's parser reads it (`_text`). ElementTree.ParseError as Python's own."""
    import xml.etree.ElementTree as ElementTree
    return ElementTree.ElementTree(ElementTree.fromstring(_text(path)[0]))
