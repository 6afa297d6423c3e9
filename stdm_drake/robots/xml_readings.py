"""What Drake's parser reads of an XML element where a reader that joins or merges would read otherwise: an element's
first text node (`split_text`), the first of elements stated twice (`content`, to compare them). Used by
`robots.xml_file`'s checks."""
from __future__ import annotations

import pathlib

from stdm_drake.errors import InputError

# What a joint, a link's inertia, a shape... states once, read as the first by Drake's parser (the others ignored
# without a word): a second one is refused where it differs from the first (two equal ones say the same; a published
# quadruped states a joint's <axis> twice). "*": every shape of SHAPES (a <geometry> holds one; a published racecar's
# also holds a <material>, which Drake's parser passes over).
SHAPES = {"box", "cylinder", "sphere", "mesh", "capsule", "ellipsoid", "plane", "heightmap", "polyline", "empty",
          "drake:capsule", "drake:ellipsoid"}
URDF_SAME_CHILDREN = {"joint": ("origin", "parent", "child", "axis", "limit", "dynamics", "mimic", "calibration",
                                "safety_controller"), "inertial": ("mass", "origin", "inertia"), "link": ("inertial",),
                      "visual": ("origin", "geometry", "material"), "collision": ("origin", "geometry"),
                      "geometry": ("*",), "material": ("color", "texture")}
SDF_SAME_CHILDREN = {"joint": ("parent", "child", "pose", "axis", "axis2"), "axis": ("xyz", "limit", "dynamics"),
                     "axis2": ("xyz", "limit", "dynamics"), "limit": ("lower", "upper", "effort", "velocity"),
                     "dynamics": ("damping", "friction", "spring_reference", "spring_stiffness"),
                     "inertial": ("mass", "pose", "inertia"), "model": ("pose", "static", "self_collide",
                                                                         "allow_auto_disable", "enable_wind"),
                     "link": ("inertial", "pose", "gravity", "self_collide", "kinematic", "must_be_base_link",
                              "enable_wind"),
                     "inertia": ("ixx", "iyy", "izz", "ixy", "ixz", "iyz"),
                     "visual": ("pose", "geometry", "material", "transparency", "cast_shadows"),
                     "material": ("ambient", "diffuse", "specular", "emissive", "script", "pbr", "lighting",
                                  "double_sided"),
                     "collision": ("pose", "geometry"), "geometry": ("*",), "box": ("size",), "sphere": ("radius",),
                     "cylinder": ("radius", "length"), "capsule": ("radius", "length"), "ellipsoid": ("radii",)}

FREE_TEXT = {"description", "author", "email", "maintainer", "license"}   # (a model.config's: no value Drake reads)


def split_text(path: pathlib.Path, tag: str, line: int, nodes: list) -> None:
    """InputError where the text of element `tag` (no child elements; `nodes`: its (kind, text), kinds "text", "cdata",
    "comment", "instruction") reads otherwise to Drake: SDFormat takes an element's first text node (CDATA its own, of
    white space too; blank text none; comments passed over, not an instruction), Python joins them all (measured)."""
    if tag in FREE_TEXT:
        return
    first = next((text if kind != "instruction" else "" for kind, text in nodes
                  if kind in ("cdata", "instruction") or (kind == "text" and text.strip())), "")
    joined = "".join(text for kind, text in nodes if kind in ("text", "cdata"))
    if first.strip() != joined.strip():
        kinds = {kind for kind, _ in nodes}
        what = ("a CDATA section" if "cdata" in kinds else "a processing instruction" if "instruction" in kinds
                else "a comment")
        raise InputError(f"{path.name}: the text of <{tag}> (line {line}) is split by {what}: {joined.strip()[:80]!r} "
                         f"to these checks, {first.strip()[:80]!r} to Drake's parser (SDFormat reads an element's first "
                         "text node); write the value in one piece")


# URDF attributes with a default (the URDF specification's, as Drake's parser reads them): stated or left out, the
# same element
# (not <limit>'s lower and upper: the specification says 0, Drake's parser reads them as unbounded)
URDF_DEFAULT_ATTRIBUTES = {"origin": {"xyz": "0 0 0", "rpy": "0 0 0"}, "axis": {"xyz": "1 0 0"},
                           "dynamics": {"damping": "0", "friction": "0"}}
BOOLEAN_WORDS = {"true": 1.0, "false": 0.0}   # (SDFormat reads a boolean as true/false or 1/0)


def differ(children, sdf: bool, materials: dict | None = None) -> bool:
    """Whether elements an element states more than once say different things (`content`); a URDF material that
    only names a material (`<material name="m"/>`) says what the file's first definition of that name says
    (`materials`: name -> that element, `first_materials`; Drake's parser keeps the first), else its sibling's."""
    defined = {} if sdf else {child.get("name"): child for child in children if child.tag == "material" and len(child)}
    defined.update(materials or {})
    return len({content(defined.get(child.get("name"), child) if child.tag == "material" and not len(child) else child)
                for child in children}) > 1


def first_materials(root) -> dict:
    """A URDF's materials by name: the first element of each name that defines one (a colour or a texture)."""
    found = {}
    for material in root.iter("material"):
        if len(material) and material.get("name") and material.get("name") not in found:
            found[material.get("name")] = material
    return found


def content(element) -> tuple:
    """What an element states, to compare two of them: its tag, attributes (those left out at their default as
    stated) and text (their words, numbers as numbers: "0 1 0" and "0 1 0.0" say the same, and booleans: "true" and
    "1") and its children's, in order."""
    attributes = {**URDF_DEFAULT_ATTRIBUTES.get(element.tag, {}), **element.attrib}
    return (element.tag, tuple(sorted((key, _words(value)) for key, value in attributes.items())),
            _words(element.text or ""), tuple(content(child) for child in element))


def _words(text: str) -> tuple:
    def word(item: str):
        try:
            return float(item)
        except ValueError:
            return BOOLEAN_WORDS.get(item.lower(), item)
    return tuple(word(item) for item in text.split())
