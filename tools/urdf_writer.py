"""Small text builders for the URDF files that tools/generate_*_urdf.py write from published numbers.

Every builder returns the lines of one URDF element (indented for a child of <robot>, no trailing
newline); a generator collects them and joins them with newlines. Geometry is primitive cylinders
only: a shape is ((radius, length), xyz, rpy) in the link frame, the cylinder's axis being its local z.
Not a package: the generators import this file by putting tools/ on sys.path.
"""


def fmt(values) -> str:
    """Numbers as URDF attribute text: space separated, each rounded to 12 decimals."""
    return " ".join(repr(round(float(x), 12)) for x in values)


def _origin_text(values) -> str:
    # already-formatted text is kept as it is (lets a caller write "0 0 0" or exact angles)
    return values if isinstance(values, str) else fmt(values)


def cylinders(tag: str, link: str, shapes, rgba: str = "") -> str:
    """<visual> (with a material named after the link, colour rgba) or <collision> elements, one per
    shape ((radius, length), xyz, rpy)."""
    out = []
    for (radius, length), xyz, rpy in shapes:
        material = (f'\n      <material name="{link}_color"><color rgba="{rgba}"/></material>'
                    if tag == "visual" else "")
        out.append(f'    <{tag}>\n      <origin xyz="{fmt(xyz)}" rpy="{fmt(rpy)}"/>\n'
                   f'      <geometry><cylinder radius="{radius}" length="{length}"/></geometry>{material}\n'
                   f'    </{tag}>')
    return "\n".join(out)


def link(name: str, mass, com, rpy, inertia, visuals, rgba: str, collisions=None) -> str:
    """A <link> with an <inertial> (mass kg; centre of mass xyz m and inertia-frame rpy in the link
    frame; inertia (ixx, ixy, ixz, iyy, iyz, izz) kg m^2 about the centre of mass) and cylinder
    visuals; the collision shapes are the visual ones unless `collisions` gives others."""
    ixx, ixy, ixz, iyy, iyz, izz = inertia
    collisions = visuals if collisions is None else collisions
    return (f'  <link name="{name}">\n    <inertial>\n      <mass value="{mass}"/>\n'
            f'      <origin xyz="{fmt(com)}" rpy="{fmt(rpy)}"/>\n'
            f'      <inertia ixx="{ixx}" ixy="{ixy}" ixz="{ixz}" iyy="{iyy}" iyz="{iyz}" izz="{izz}"/>\n'
            f'    </inertial>\n{cylinders("visual", name, visuals, rgba)}\n'
            f'{cylinders("collision", name, collisions)}\n  </link>')


def frame_link(name: str) -> str:
    """A massless, geometry-free <link>: a named frame (flange, tool point) for a fixed joint."""
    return f'  <link name="{name}"/>'


def revolute_joint(name: str, parent: str, child: str, xyz, rpy, lower: float | None, upper: float | None,
                   velocity, effort) -> str:
    """A revolute <joint> about the child frame's z axis, with position limits (rad), velocity limit
    (rad/s) and effort limit (N m); velocity and effort are written as given (str()). lower = upper =
    None writes a "continuous" joint: no position limits."""
    kind, bounds = ("continuous", "") if lower is None and upper is None else (
        "revolute", f'lower="{float(lower)!r}" upper="{float(upper)!r}" ')
    return (f'  <joint name="{name}" type="{kind}">\n'
            f'    <parent link="{parent}"/><child link="{child}"/>\n'
            f'    <origin xyz="{fmt(xyz)}" rpy="{fmt(rpy)}"/>\n    <axis xyz="0 0 1"/>\n'
            f'    <limit {bounds}velocity="{velocity}" effort="{effort}"/>\n'
            f'  </joint>')


def fixed_joint(name: str, parent: str, child: str, xyz="0 0 0", rpy="0 0 0") -> str:
    """A fixed <joint> on one line; xyz and rpy are numbers (written with fmt) or ready-made text."""
    return (f'  <joint name="{name}" type="fixed"><parent link="{parent}"/><child link="{child}"/>'
            f'<origin xyz="{_origin_text(xyz)}" rpy="{_origin_text(rpy)}"/></joint>')


def transmission(joint: str, base: str) -> str:
    """A <transmission> (effort interface, reduction 1) named {base}_trans that gives `joint` an
    actuator {base}_motor when the file is parsed."""
    return (f'  <transmission name="{base}_trans">\n'
            '    <type>transmission_interface/SimpleTransmission</type>\n'
            f'    <joint name="{joint}"><hardwareInterface>hardware_interface/EffortJointInterface'
            '</hardwareInterface></joint>\n'
            f'    <actuator name="{base}_motor"><mechanicalReduction>1</mechanicalReduction></actuator>\n'
            '  </transmission>')
