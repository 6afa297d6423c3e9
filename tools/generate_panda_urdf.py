"""Write models/panda.urdf (the Franka Emika Panda arm with its hand) from published numbers.

Sources (numbers only):
- kinematics: Franka Emika's modified (Craig) DH table of the Panda, with the flange 0.107 m along
  link 7's z axis;
- joint position, velocity and torque limits: Franka Emika's Panda datasheet;
- link masses, centres of mass and inertias: C. Gaz, M. Cognetti, A. Oliva, P. Robuffo Giordano,
  A. De Luca, "Dynamic Identification of the Franka Emika Panda Robot With Retrieval of Feasible
  Parameters Using Penalty-Based Optimization", IEEE RA-L 4(4), 2019 (tables VIII and IX of its
  supplementary material, as the authors list them in github.com/marcocognetti/FrankaEmikaPandaDynModel);
- the hand: Franka's default end-effector load (mass, centre of mass and inertia in the flange frame)
  and its tool-centre-point offset.
The base mass is a plausible round value: the base is welded, so it plays no part in the dynamics.
The cylinders are a rough outline of the links, drawn for this file (no meshes).
Run: python tools/generate_panda_urdf.py  (rewrites models/panda.urdf).
"""
import math
import pathlib
import sys

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import urdf_writer as urdf  # noqa: E402  (tools/urdf_writer.py, next to this file)

PI = math.pi
ROOT = pathlib.Path(__file__).resolve().parents[1]

# Modified DH, row i (joint i, i = 1..7): a_{i-1} (m), d_i (m), alpha_{i-1} (rad); the joint angle adds
# a rotation about the new z axis. Frame i is the DH frame of link i (panda_link<i>).
DH = [(0.0, 0.333, 0.0), (0.0, 0.0, -PI / 2), (0.0, 0.316, PI / 2), (0.0825, 0.0, PI / 2),
      (-0.0825, 0.384, -PI / 2), (0.0, 0.0, PI / 2), (0.088, 0.0, PI / 2)]
FLANGE_D = 0.107  # link 7 origin to the flange, along link 7's z axis (m)

# Datasheet limits per joint: (lower, upper) rad, velocity rad/s, torque N m.
Q_MIN = [-2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973]
Q_MAX = [2.8973, 1.7628, 2.8973, -0.0698, 2.8973, 3.7525, 2.8973]
VELOCITY = [2.1750, 2.1750, 2.1750, 2.1750, 2.6100, 2.6100, 2.6100]
EFFORT = [87, 87, 87, 87, 12, 12, 12]

# Identified link parameters (Gaz et al. 2019), in each link's DH frame: mass (kg), centre of mass (m),
# inertia (ixx, ixy, ixz, iyy, iyz, izz) kg m^2 about the centre of mass, axes parallel to the link frame.
# Link 1's centre of mass along the joint 1 axis cannot be identified with the base fixed (it moves no
# joint torque); the published table gives 0 there, kept here.
ARM_INERTIALS = [
    (4.970684, (3.875e-03, 2.081e-03, 0.0),
     (7.0337e-01, -1.3900e-04, 6.7720e-03, 7.0661e-01, 1.9169e-02, 9.1170e-03)),
    (0.646926, (-3.141e-03, -2.872e-02, 3.495e-03),
     (7.9620e-03, -3.9250e-03, 1.0254e-02, 2.8110e-02, 7.0400e-04, 2.5995e-02)),
    (3.228604, (2.7518e-02, 3.9252e-02, -6.6502e-02),
     (3.7242e-02, -4.7610e-03, -1.1396e-02, 3.6155e-02, -1.2805e-02, 1.0830e-02)),
    (3.587895, (-5.317e-02, 1.04419e-01, 2.7454e-02),
     (2.5853e-02, 7.7960e-03, -1.3320e-03, 1.9552e-02, 8.6410e-03, 2.8323e-02)),
    (1.225946, (-1.1953e-02, 4.1065e-02, -3.8437e-02),
     (3.5549e-02, -2.1170e-03, -4.0370e-03, 2.9474e-02, 2.2900e-04, 8.6270e-03)),
    (1.666555, (6.0149e-02, -1.4117e-02, -1.0517e-02),
     (1.9640e-03, 1.0900e-04, -1.1580e-03, 4.3540e-03, 3.4100e-04, 5.4330e-03)),
    (7.35522e-01, (1.0517e-02, -4.252e-03, 6.1597e-02),
     (1.2516e-02, -4.2800e-04, -1.1960e-03, 1.0027e-02, -7.4100e-04, 4.8150e-03)),
]
# Base (welded: a plausible value that no joint torque depends on).
BASE_INERTIAL = (0.63, (-0.041, 0.0, 0.05), (0.00315, 0.0, 0.00015, 0.00388, 0.0, 0.00429))
# Franka hand as the default end-effector load, in the flange frame.
HAND_INERTIAL = (0.73, (-0.01, 0.0, 0.03), (0.001, 0.0, 0.0, 0.0025, 0.0, 0.0017))
TCP_Z, TCP_YAW = 0.1034, -PI / 4  # tool centre point: along the flange z axis, turned about it (m, rad)

# Cylinders ((radius, length), xyz, rpy) in each link frame; a cylinder's axis is its local z.
# rpy (pi/2, 0, 0) lays it along the link's y axis, (0, pi/2, 0) along x.
ALONG_X, ALONG_Y, ALONG_Z = (0, PI / 2, 0), (PI / 2, 0, 0), (0, 0, 0)
HAND_Y = (PI / 2, 0, TCP_YAW)  # along the hand's finger-travel axis (flange y turned by TCP_YAW)
FINGER = (math.cos(TCP_YAW + PI / 2), math.sin(TCP_YAW + PI / 2))  # that axis in the flange x-y plane
VISUAL = {
    "panda_link0": [((0.09, 0.14), (0, 0, 0.07), ALONG_Z), ((0.06, 0.1), (-0.09, 0, 0.05), ALONG_Z)],
    "panda_link1": [((0.065, 0.2), (0, 0, -0.1), ALONG_Z), ((0.065, 0.13), (0, 0, 0), ALONG_Y)],
    "panda_link2": [((0.065, 0.13), (0, 0, 0), ALONG_Z), ((0.06, 0.15), (0, -0.1, 0), ALONG_Y)],
    "panda_link3": [((0.06, 0.15), (0, 0, -0.075), ALONG_Z), ((0.06, 0.12), (0.0825, 0, 0), ALONG_Y)],
    "panda_link4": [((0.06, 0.12), (0, 0, 0), ALONG_Z), ((0.06, 0.13), (-0.0825, 0.07, 0), ALONG_Y)],
    "panda_link5": [((0.06, 0.21), (0, 0, -0.135), ALONG_Z), ((0.04, 0.1), (-0.02, 0, -0.05), ALONG_Z)],
    "panda_link6": [((0.06, 0.12), (0, 0, 0), ALONG_Z), ((0.045, 0.09), (0.045, 0, 0), ALONG_X),
                    ((0.05, 0.06), (0.088, 0.01, 0), ALONG_Y)],
    "panda_link7": [((0.05, 0.09), (0, 0, 0.062), ALONG_Z)],
    "panda_hand": [((0.03, 0.2), (0, 0, 0.045), HAND_Y),
                   ((0.01, 0.05), (0.02 * FINGER[0], 0.02 * FINGER[1], 0.085), ALONG_Z),
                   ((0.01, 0.05), (-0.02 * FINGER[0], -0.02 * FINGER[1], 0.085), ALONG_Z)],
}
# Collision: the visual outline, a little slimmer where links fold against each other.
COLLISION = {
    **VISUAL,
    "panda_link1": [((0.06, 0.19), (0, 0, -0.1), ALONG_Z), ((0.06, 0.12), (0, 0, 0), ALONG_Y)],
    "panda_link2": [((0.06, 0.12), (0, 0, 0), ALONG_Z), ((0.055, 0.14), (0, -0.1, 0), ALONG_Y)],
    "panda_link3": [((0.055, 0.14), (0, 0, -0.075), ALONG_Z), ((0.055, 0.11), (0.0825, 0, 0), ALONG_Y)],
    "panda_link4": [((0.055, 0.11), (0, 0, 0), ALONG_Z), ((0.05, 0.12), (-0.0825, 0.07, 0), ALONG_Y)],
    "panda_link5": [((0.05, 0.16), (0, 0, -0.17), ALONG_Z), ((0.035, 0.08), (-0.02, 0, -0.06), ALONG_Z)],
    "panda_link6": [((0.055, 0.11), (0, 0, 0), ALONG_Z), ((0.04, 0.08), (0.045, 0, 0), ALONG_X),
                    ((0.045, 0.05), (0.088, 0.01, 0), ALONG_Y)],
    "panda_link7": [((0.045, 0.08), (0, 0, 0.067), ALONG_Z)],
}
WHITE, GREY, DARK = "0.95 0.95 0.95 1", "0.75 0.75 0.78 1", "0.2 0.2 0.2 1"
COLORS = {"panda_link0": DARK, "panda_link7": DARK, "panda_hand": GREY}


def joint_origin(a: float, d: float, alpha: float):
    """URDF origin (xyz, rpy) of a modified-DH step: rotate alpha about x, move a along x, then d along the
    new z axis (whose direction in the parent frame is (0, -sin alpha, cos alpha)). Adding 0.0 turns a
    -0.0 into 0.0 for the file's sake."""
    return (a, -math.sin(alpha) * d + 0.0, math.cos(alpha) * d), (alpha, 0.0, 0.0)


def check_inertia(name: str, mass: float, inertia) -> None:
    """Raise unless the mass is positive and the inertia a physical one: principal moments positive and
    each at most the sum of the other two (Drake refuses other inertias when the plant is built)."""
    ixx, ixy, ixz, iyy, iyz, izz = inertia
    moments = np.linalg.eigvalsh(np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]]))
    if not (mass > 0 and moments[0] > 0 and moments[2] <= moments[0] + moments[1]):
        raise ValueError(f"{name}: mass {mass} or principal moments {moments} are not physical")


def urdf_text():
    s = ['<?xml version="1.0"?>',
         '<!-- Franka Emika Panda (7 joints) with the Franka hand, for stdm-drake. Numbers from published',
         '     sources: Franka Emika\'s modified DH table and datasheet joint limits; link masses, centres of',
         '     mass and inertias identified by Gaz, Cognetti, Oliva, Robuffo Giordano and De Luca (IEEE RA-L',
         '     2019); the hand as Franka\'s default end-effector load and tool-centre-point offset. DH frames:',
         '     every joint rotates about its local z axis; panda_link8 is the flange. Primitive cylinders only',
         '     (no meshes). Generated by tools/generate_panda_urdf.py; edit that script, not this file. -->',
         '<robot name="panda">']
    inertials = [("panda_link0", BASE_INERTIAL)] + [(f"panda_link{i}", values)
                                                     for i, values in enumerate(ARM_INERTIALS, start=1)]
    inertials.append(("panda_hand", HAND_INERTIAL))
    for name, (mass, com, inertia) in inertials:
        check_inertia(name, mass, inertia)
        s.append(urdf.link(name, mass, com, (0, 0, 0), inertia, VISUAL[name], COLORS.get(name, WHITE),
                           COLLISION[name]))
    for i, (a, d, alpha) in enumerate(DH, start=1):
        xyz, rpy = joint_origin(a, d, alpha)
        s.append(urdf.revolute_joint(f"panda_joint{i}", f"panda_link{i - 1}", f"panda_link{i}", xyz, rpy,
                                     Q_MIN[i - 1], Q_MAX[i - 1], VELOCITY[i - 1], EFFORT[i - 1]))
    s += [urdf.frame_link("panda_link8"),
          urdf.fixed_joint("panda_joint8", "panda_link7", "panda_link8", (0, 0, FLANGE_D), (0, 0, 0)),
          urdf.fixed_joint("panda_hand_joint", "panda_link8", "panda_hand", (0, 0, 0), (0, 0, 0)),
          urdf.frame_link("panda_hand_tcp"),
          urdf.fixed_joint("panda_hand_tcp_joint", "panda_hand", "panda_hand_tcp", (0, 0, TCP_Z), (0, 0, TCP_YAW))]
    s += [urdf.transmission(f"panda_joint{i}", f"panda_joint{i}") for i in range(1, len(DH) + 1)]
    s.append('</robot>\n')
    return "\n".join(s)


def main():
    path = ROOT / "models" / "panda.urdf"
    path.write_text(urdf_text())
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
