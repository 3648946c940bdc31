"""A URDF link that a joint of the arm moves must carry mass or inertia (itself, or by a body fixed to
it): a joint that moves nothing makes ``M(q)`` singular, and the law's ``M(q)^-1`` meaningless. Such a
link is refused when the arm is read, in one error naming it, however its zero is written; a link with
mass and no inertia or inertia and no mass is accepted, and so is a link with nothing that no joint
moves (a world frame, a camera frame fixed to a moved link)."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from dvfc.analysis.cli import app
from dvfc.models.robot import Robot, RobotModelError

from helpers import write

runner = CliRunner()
Z1 = Path(__file__).parent / "data" / "z1_bracket.urdf"

HEAVY = '<mass value="1.0"/><inertia ixx="1e-3" ixy="0" ixz="0" iyy="1e-3" iyz="0" izz="1e-3"/>'
"""An ``<inertial>``'s mass and inertia: a link with both."""

ZEROS = {
    "zero mass and inertia": '<inertial><origin xyz="0 0 0"/><mass value="0"/><inertia ixx="0" ixy="0" ixz="0" '
                             'iyy="0" iyz="0" izz="0"/></inertial>',
    "zeros written as floats": '<inertial><origin xyz="0.1 0 0"/><mass value="0.0"/><inertia ixx="0.0" ixy="0.0" '
                               'ixz="0.0" iyy="0e0" iyz="0.0" izz="-0.0"/></inertial>',
    "zero mass without inertia": '<inertial><mass value="0"/></inertial>',
    "zero inertia without mass": '<inertial><inertia ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"/></inertial>',
    "an empty inertial": "<inertial/>",
    "no inertial": "",
}  # fmt: skip
"""Ways a URDF link says it has neither mass nor inertia."""


def link(name: str, inertial: str | None = None, com: str = "0.05 0 0.05") -> str:
    """A link; ``inertial`` its ``<inertial>`` element (None: :data:`HEAVY` at ``com``)."""
    if inertial is None:
        inertial = f'<inertial><origin xyz="{com}" rpy="0 0 0"/>{HEAVY}</inertial>'
    return f'<link name="{name}">{inertial}</link>'


def joint(name: str, parent: str, child: str, kind: str = "revolute", axis: str = "0 0 1") -> str:
    limit = '<limit lower="-3" upper="3" effort="10" velocity="3"/>' if kind == "revolute" else ""
    return (f'<joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>'
            f'<origin xyz="0 0 0.1" rpy="0 0 0"/><axis xyz="{axis}"/>{limit}</joint>')  # fmt: skip


def arm(tmp_path: Path, links: dict[str, str | None] | None = None, extra: str = "") -> Path:
    """A two-joint arm: ``world`` (nothing) fixed to ``base``, which joint ``j1`` (about z) turns ``l1`` on,
    which joint ``j2`` (about y) turns ``l2`` on, with the camera frame ``cam`` (nothing) fixed to ``l2``.
    ``links`` replaces links' ``<inertial>`` (None: :data:`HEAVY`); ``extra`` adds elements."""
    inertial = {"world": "", "base": None, "l1": None, "l2": None, "cam": ""} | (links or {})
    body = "".join(link(name, value) for name, value in inertial.items())
    body += joint("world_joint", "world", "base", "fixed") + joint("j1", "base", "l1")
    body += joint("j2", "l1", "l2", axis="0 1 0") + joint("cam_joint", "l2", "cam", "fixed")
    path = tmp_path / "arm.urdf"
    path.write_text(f'<robot name="arm">{body}{extra}</robot>')
    return path


def regular(robot: Robot) -> float:
    """The smallest eigenvalue of ``M(q)`` over a few configurations (positive: the arm can be driven)."""
    mass = robot.function("M", robot.mass_matrix)
    return min(np.linalg.eigvalsh(np.asarray(mass(q, 0))).min() for q in ([0.0, 0.0], [0.3, -0.7], [2.0, 1.2]))


@pytest.mark.parametrize("written", list(ZEROS.values()), ids=list(ZEROS))
@pytest.mark.parametrize("moved", ["l1", "l2"])
def test_a_moved_link_without_mass_or_inertia_is_refused_naming_it(tmp_path, moved, written):
    """The first or the last link the joints move, with neither mass nor inertia however that is written
    (zeros, zeros as floats or ``-0.0``, a mass or an inertia alone at zero, an empty or absent
    ``<inertial>``): reading the arm raises one error naming that link and no other, saying what is
    missing and why."""
    path = arm(tmp_path, {moved: written})
    with pytest.raises(RobotModelError) as refused:
        Robot(path, "cam")
    message = str(refused.value)
    assert "\n" not in message and f"link(s) '{moved}' carry no <inertial> mass or inertia" in message
    assert "M(q) would be singular" in message
    assert re.findall(r"'(\w+)'", message) == [moved]


def test_every_moved_link_without_mass_or_inertia_is_named_in_one_error(tmp_path):
    """Both moved links zero: one error naming both, in the order of the chain."""
    path = arm(tmp_path, {"l1": ZEROS["zero mass and inertia"], "l2": ZEROS["no inertial"]})
    with pytest.raises(RobotModelError, match=r"link\(s\) 'l1', 'l2' carry no <inertial> mass or inertia"):
        Robot(path, "cam")


def inertial(com: str, mass: str, diagonal: str) -> str:
    """An ``<inertial>`` with its centre of mass ``com``, ``mass`` and the inertia's diagonal ``diagonal``."""
    ixx, iyy, izz = diagonal.split()
    return (
        f'<inertial><origin xyz="{com}"/><mass value="{mass}"/><inertia ixx="{ixx}" ixy="0" ixz="0" '
        f'iyy="{iyy}" iyz="0" izz="{izz}"/></inertial>'
    )


@pytest.mark.parametrize(("what", "element"), [
    ("inertia without mass", inertial("0 0 0", "0", "2e-3 2e-3 2e-3")),
    ("mass without inertia", inertial("0.1 0.05 0.05", "0.5", "0 0 0")),
    ("a tiny mass", inertial("0.1 0.05 0.05", "1e-6", "0 0 0")),
    ("a tiny inertia", inertial("0 0 0", "0", "1e-9 1e-9 1e-9")),
])  # fmt: skip
@pytest.mark.parametrize("moved", ["l1", "l2"])
def test_a_moved_link_with_mass_or_inertia_alone_is_accepted(tmp_path, moved, what, element):
    """A moved link with inertia but zero mass, or with mass off its joint's axis but zero inertia, or a tiny
    mass or inertia: the arm is read, and its ``M(q)`` is positive definite (smallest eigenvalue above
    1e-12 kg m^2, round-off of entries of order 1e-2) at three configurations."""
    robot = Robot(arm(tmp_path, {moved: element}), "cam")
    assert robot.n == 2 and regular(robot) > 1e-12, what


@pytest.mark.parametrize("fixed", ["world", "base", "cam"])
def test_a_link_without_mass_that_no_joint_moves_is_accepted(tmp_path, fixed):
    """A link with neither mass nor inertia that no joint moves relative to its parent: the world frame,
    the base (fixed to the world) and the camera frame (fixed to a moved link that has mass). Each zero on
    its own and all three at once; ``M(q)`` is positive definite."""
    zero = ZEROS["zero mass and inertia"]
    assert regular(Robot(arm(tmp_path, {fixed: zero}), "cam")) > 1e-12
    assert regular(Robot(arm(tmp_path, dict.fromkeys(("world", "base", "cam"), zero)), "cam")) > 1e-12


def test_a_moved_link_without_mass_carrying_a_body_fixed_to_it_is_accepted(tmp_path):
    """``l2`` with nothing, but a tool with mass fixed to it: the joint moves the tool, so the arm is read
    (``M(q)`` positive definite); the same tool with nothing of its own does not save ``l2``, which is
    then refused by name (the tool, not moved by a joint of its own, is not named)."""
    zero = ZEROS["zero mass and inertia"]
    tool = link("tool") + joint("tool_joint", "l2", "tool", "fixed")
    assert regular(Robot(arm(tmp_path, {"l2": zero}, tool), "cam")) > 1e-12
    bare = link("tool", zero) + joint("tool_joint", "l2", "tool", "fixed")
    with pytest.raises(RobotModelError, match=r"link\(s\) 'l2' carry no"):
        Robot(arm(tmp_path, {"l2": zero}, bare), "cam")


def test_a_link_moved_only_by_a_joint_off_the_cameras_chain_counts_as_fixed(tmp_path):
    """A revolute joint that is not on the way to the camera is held fixed: a link it carries with nothing
    of its own is not refused (no joint of the arm moves it), and a body with mass on it counts for the
    moved link it is fixed to through that joint (``l2`` with nothing, a finger with mass on a joint off
    the chain: accepted)."""
    zero = ZEROS["zero mass and inertia"]
    finger = link("finger", zero) + joint("finger_joint", "l2", "finger")
    assert Robot(arm(tmp_path, extra=finger), "cam").n == 2
    heavy = link("finger") + joint("finger_joint", "l2", "finger")
    robot = Robot(arm(tmp_path, {"l2": zero}, heavy), "cam")
    assert robot.n == 2 and regular(robot) > 1e-12


def test_a_command_refuses_an_arm_with_a_zeroed_moved_link_in_one_line(tmp_path):
    """The Z1-like arm with joint 5's link given an ``<inertial>`` of zeros (nothing else fixed to it:
    joint 6's link follows on a joint of its own): ``dvfc pose`` exits 2 with one line naming the field
    and the link, and no traceback."""
    text, count = re.subn(r'(<link name="link05"><inertial>)<mass value="[^"]*"/>(.*?)<inertia [^>]*/>',
                          r'\1<mass value="0"/>\2<inertia ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"/>',
                          Z1.read_text())  # fmt: skip
    assert count == 1
    urdf = tmp_path / "arm.urdf"
    urdf.write_text(text)

    def edit(data: dict) -> None:
        data["robot"] = {"urdf": str(urdf), "camera_frame": "camera_link", "q0": [0.5, 1.0, -2.0, 1.0, 0.3, 0.5]}
        for key in ("xyz", "rpy"):
            data["target"].pop(key)
        data["target"]["relative_to_camera"] = {"xyz": [0.0, 0.0, 0.35], "rpy": [0.0, 0.0, 0.0]}

    result = runner.invoke(app, ["pose", str(write(tmp_path, edit))])
    assert result.exit_code == 2, result.output
    assert "Traceback" not in result.output
    lines = result.stderr.strip().splitlines()
    assert lines == [
        "error: robot.urdf: arm.urdf: link(s) 'link05' carry no <inertial> mass or inertia, nor does anything "
        "fixed to them: M(q) would be singular; give each moving link its inertial data"
    ], result.stderr
