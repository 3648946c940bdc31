"""Manipulator dynamics (33) and the camera's body Jacobian (34), from a URDF.

The rigid-body algorithms come from adam-robotics (CasADi expressions of the URDF):
the mass matrix ``M(q)``, gravity ``g(q)`` and forward kinematics. The Coriolis
matrix is built from the Christoffel symbols of ``M``, so ``Mdot - 2C`` is
skew-symmetric by construction (the property the passivity of (33) rests on), and
the body Jacobian of the camera frame is the derivative of its forward kinematics,
``J_b`` column ``i`` = ``(g_wc^-1 dg_wc/dq_i)^vee``.
"""

from __future__ import annotations

import difflib
import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from functools import cached_property
from importlib.metadata import PackageNotFoundError, distribution
from pathlib import Path

import casadi as cs
import numpy as np

from dvfc.models.inertia import InertiaModelError, MassBounds, mass_matrix_bounds, urdf_attribute
from dvfc.models.lie import SE3, Matrix, vee

_ERD = "cmeel.prefix/share/example-robot-data/robots"
_SHIPPED = Path(__file__).parent / "urdf"

BUILTIN_URDF: dict[str, str | Path] = {
    "ur5": f"{_ERD}/ur_description/urdf/ur5_robot.urdf",
    "panda": f"{_ERD}/panda_description/urdf/panda.urdf",
    "xarm7": f"{_ERD}/xarm_description/urdf/xarm7.urdf",
    "puma560": _SHIPPED / "puma560.urdf",
    "planar2dd": _SHIPPED / "planar2dd.urdf",
}
"""Built-in arms: name -> URDF, a path inside the example-robot-data distribution (``str``)
or a file shipped with this package (``Path``)."""

BUILTIN_CAMERA_FRAME = {
    "ur5": "tool0", "panda": "panda_link8", "xarm7": "link_eef", "puma560": "link6", "planar2dd": "camera_link",
}  # fmt: skip

BUILTIN_ARMATURE = {
    "puma560": tuple(
        jm * g**2
        for jm, g in zip(
            (200e-6, 200e-6, 200e-6, 33e-6, 33e-6, 33e-6),
            (-62.6111, 107.815, -53.7063, 76.0364, 71.923, 76.686),
            strict=True,
        )
    ),
}
"""Reflected motor inertias ``G_i^2 J_m,i`` (kg m^2) added to the diagonal of ``M(q)``: not
rigid-body data, so not in the URDF. Puma 560: motor inertias ``J_m`` and gear ratios ``G``
of Armstrong et al. (1986) as in Corke's Robotics Toolbox (they dominate the wrist)."""


TASK_DIM = 6
"""The dimension of the camera's twist: the task the law (42) commands."""


def spans_the_task(n: int) -> bool:
    """Whether an arm of ``n`` joints can give ``J_b pinv(J_b) = I_6``, which the law's cancellation
    ((40)-(41), Lemma 2) and so Theorems 1-2 need: ``n >= 6`` (with fewer joints ``J_b`` has rank < 6)."""
    return n >= TASK_DIM


class RobotModelError(ValueError):
    """The URDF cannot be read, or it does not have the frame or joints asked for."""


class ChainError(RobotModelError):
    """The chain from the URDF's root to the camera link cannot be modelled: no such link, no
    movable joint on the way, or a joint of a kind the toolkit does not support."""


@dataclass(frozen=True)
class Mimic:
    """A URDF ``<mimic>`` joint: ``q_joint = multiplier q_master + offset``."""

    master: str
    multiplier: float = 1.0
    offset: float = 0.0


@dataclass(frozen=True)
class JointLimits:
    """The URDF's ``<limit>`` of each joint of the chain (``inf`` where the file gives none):
    ``effort`` (N m or N), ``velocity`` (rad/s or m/s), ``lower``/``upper`` (rad or m)."""

    effort: np.ndarray
    velocity: np.ndarray
    lower: np.ndarray
    upper: np.ndarray


@dataclass(frozen=True)
class Payload:
    """A rigid body fixed to the camera link, unknown to the controller (a camera, a gripper).

    ``com`` is its centre of mass in the link frame (m); ``inertia`` its inertia about the
    centre of mass, axes of the link frame, as the URDF's ``[ixx, ixy, ixz, iyy, iyz, izz]``.
    """

    mass: float
    com: tuple[float, float, float] = (0.0, 0.0, 0.0)
    inertia: tuple[float, ...] = (0.0,) * 6


def builtin_urdf(name: str) -> Path:
    """Path of a built-in arm's URDF (from example-robot-data or this package; nothing downloaded)."""
    if name not in BUILTIN_URDF:
        raise RobotModelError(f"unknown robot model {name!r}; built-in models: {', '.join(sorted(BUILTIN_URDF))}")
    where = BUILTIN_URDF[name]
    try:
        path = where if isinstance(where, Path) else Path(str(distribution("example-robot-data").locate_file(where)))
    except PackageNotFoundError as exc:
        raise RobotModelError("the package example-robot-data is not installed") from exc
    if not path.is_file():
        raise RobotModelError(f"the URDF of {name!r} is missing: {path}")
    return path


def _parse(urdf: Path) -> ET.Element:
    try:
        return ET.parse(urdf).getroot()
    except (ET.ParseError, OSError) as exc:
        raise RobotModelError(f"cannot read URDF {urdf}: {exc}") from exc


def chain_joints(urdf: Path, frame: str) -> list[str]:
    """Names of the movable joints from the URDF's root to ``frame``, root first (``mimic``
    joints included).

    Raises
    ------
    ChainError
        No link ``frame``, no movable joint on the way, or a joint on the way that is neither
        revolute nor continuous (a prismatic joint: the inertia bounds of
        :mod:`dvfc.models.inertia` and the planar and spatial loops are for revolute joints).
    """
    root = _parse(urdf)
    links = {urdf_attribute(link, ".", "name", RobotModelError) for link in root.iter("link")}
    if frame not in links:
        close = difflib.get_close_matches(frame, sorted(links), n=3, cutoff=0.3) or sorted(links)[:6]
        raise ChainError(f"URDF {urdf.name} has no link named {frame!r}; closest: {', '.join(map(repr, close))}")
    parent_joint = {urdf_attribute(j, "child", "link", RobotModelError): j
                    for j in root.iter("joint") if j.find("child") is not None}
    names: list[str] = []
    link = frame
    while link in parent_joint:
        joint = parent_joint[link]
        kind = joint.get("type")
        if kind in ("prismatic", "planar", "floating"):
            raise ChainError(
                f"joint {joint.get('name')!r} is {kind}, on the chain from the root of {urdf.name} to {frame!r}: "
                "only revolute and continuous joints are supported; mount the camera on a link above it"
            )
        if kind in ("revolute", "continuous"):
            names.append(urdf_attribute(joint, ".", "name", RobotModelError))
        link = urdf_attribute(joint, "parent", "link", RobotModelError)
    if not names:
        raise ChainError(f"no movable joint between the root of {urdf.name} and {frame!r}")
    return names[::-1]


def mimic_joints(urdf: Path) -> dict[str, Mimic]:
    """The URDF's movable ``<mimic>`` joints: name -> :class:`Mimic` (the URDF's defaults:
    multiplier 1, offset 0).

    Raises
    ------
    RobotModelError
        A mimic joint whose master is not a joint of the URDF.
    """
    joints = _parse(urdf).findall("joint")
    names = {joint.get("name") for joint in joints}
    out = {}
    for joint in joints:
        tag = joint.find("mimic")
        if tag is None or joint.get("type") == "fixed":
            continue
        name = urdf_attribute(joint, ".", "name", RobotModelError)
        master = urdf_attribute(tag, ".", "joint", RobotModelError)
        if master not in names:
            raise RobotModelError(f"joint {name!r} of {urdf.name} mimics {master!r}: no such joint")
        multiplier, offset = float(tag.get("multiplier", 1.0)), float(tag.get("offset", 0.0))
        out[name] = Mimic(master, multiplier, offset)
    return out


def coupling(chain: list[str], mimic: dict[str, Mimic]) -> tuple[list[str], list[str], np.ndarray, np.ndarray]:
    """The independent joints of ``chain`` and every joint that moves with them:
    ``(joints, moving, T, c)`` with ``q_moving = T q_joints + c``.

    ``joints`` are the chain's joints that mimic none; ``moving`` is ``joints`` followed by the
    chain's mimic joints and every other mimic joint whose master, followed through mimics of
    mimics, is one of ``joints``. A mimic joint whose master is held fixed at zero (a movable
    joint off the chain) sits at its offset.

    Raises
    ------
    RobotModelError
        Mimic joints that follow each other in a cycle (:class:`ChainError`: a chain of mimic
        joints only).
    """
    joints = [name for name in chain if name not in mimic]
    if not joints:
        raise ChainError(f"every joint of the chain ({', '.join(map(repr, chain))}) mimics another")
    n = len(joints)

    def resolve(name: str, seen: tuple[str, ...]) -> tuple[np.ndarray, float]:
        if name in joints:
            return np.eye(n)[joints.index(name)], 0.0
        if name not in mimic:
            return np.zeros(n), 0.0  # a movable joint off the chain, held fixed at zero
        if name in seen:
            cycle = " -> ".join(map(repr, (*seen, name)))
            raise RobotModelError(f"the mimic joints {cycle} follow each other in a cycle")
        m = mimic[name]
        row, offset = resolve(m.master, (*seen, name))
        return m.multiplier * row, m.multiplier * offset + m.offset

    rows = {name: resolve(name, ()) for name in (*joints, *mimic)}
    moving = [*joints, *(name for name in mimic if name in chain or np.any(rows[name][0]))]
    t = np.array([rows[name][0] for name in moving]).reshape(len(moving), n)
    return joints, moving, t, np.array([rows[name][1] for name in moving])


def _limit_value(joint: ET.Element, key: str, urdf: Path) -> float:
    """One attribute of a joint's ``<limit>``: ``effort`` and ``velocity`` positive and finite (the
    URDF requires both in every ``<limit>``, and a ``<limit>`` on a revolute joint; a continuous
    joint without one has none: ``inf``), ``lower`` and ``upper`` finite (``-inf``/``inf`` when
    absent; a continuous joint's are ignored, as the URDF ignores them)."""
    name, kind, limit = joint.get("name"), joint.get("type"), joint.find("limit")
    text = None if limit is None else limit.get(key)
    if key in ("lower", "upper") and (text is None or kind == "continuous"):
        return -math.inf if key == "lower" else math.inf
    if limit is None and kind == "continuous":
        return math.inf
    unit = {"effort": "N m", "velocity": "rad/s", "lower": "rad", "upper": "rad"}[key]
    if text is None:
        raise RobotModelError(
            f"joint {name!r} of {urdf.name}: no {key} limit (<limit {key}=...>, {unit}; the URDF requires "
            "effort and velocity in every <limit> and a <limit> on a revolute joint)"
        )
    try:
        value = float(text)
    except ValueError:
        raise RobotModelError(f"joint {name!r} of {urdf.name}: {key} limit {text!r} is not a number") from None
    if not math.isfinite(value) or (key in ("effort", "velocity") and value <= 0):
        raise RobotModelError(
            f"joint {name!r} of {urdf.name}: {key} limit {text} must be a positive number ({unit}); "
            "give the joint's rated value (a URDF has no 'unlimited' value)"
        )
    return value


def joint_limits(urdf: Path, joints: list[str]) -> JointLimits:
    """The ``<limit>`` attributes of ``joints`` (in that order) from the URDF, checked
    (:func:`_limit_value`; ``lower <= upper``).

    Raises
    ------
    RobotModelError
        A zero, negative, non-finite or non-numeric limit, an effort or velocity limit missing
        on a revolute joint, or ``lower > upper``: the message names the joint and the field.
    """
    by_name = {j.get("name"): j for j in _parse(urdf).findall("joint")}  # not <transmission>
    values: dict[str, list[float]] = {key: [] for key in ("effort", "velocity", "lower", "upper")}
    for name in joints:
        joint = by_name[name]
        for key, out in values.items():
            out.append(_limit_value(joint, key, urdf))
        if values["lower"][-1] > values["upper"][-1]:
            raise RobotModelError(
                f"joint {name!r} of {urdf.name}: lower limit {values['lower'][-1]:g} exceeds upper limit "
                f"{values['upper'][-1]:g}"
            )
    return JointLimits(**{key: np.asarray(v) for key, v in values.items()})


def massless_links(urdf: Path, moving: list[str]) -> list[str]:
    """The child links of the joints ``moving`` that carry no mass or inertia, nor does anything
    fixed to them (joints outside ``moving`` count as fixed, :func:`frozen_urdf`): a joint
    moving no inertia makes ``M(q)`` of (33) singular."""
    root = _parse(urdf)
    heavy = set()
    for link in root.findall("link"):
        inertial = link.find("inertial")
        mass = None if inertial is None else inertial.find("mass")
        inertia = None if inertial is None else inertial.find("inertia")
        values = [mass.get("value", "0")] if mass is not None else []
        values += [inertia.get(k, "0") for k in ("ixx", "iyy", "izz")] if inertia is not None else []
        try:
            if any(float(v) > 0 for v in values):
                heavy.add(link.get("name"))
        except ValueError:
            heavy.add(link.get("name"))  # not a number: the dynamics' parser names it
    joints = [j for j in root.findall("joint") if j.find("parent") is not None and j.find("child") is not None]
    rigid: dict[str, list[str]] = {}
    for j in joints:
        if j.get("name") not in moving:
            parent = urdf_attribute(j, "parent", "link", RobotModelError)
            rigid.setdefault(parent, []).append(urdf_attribute(j, "child", "link", RobotModelError))

    def carries(link: str) -> bool:
        return link in heavy or any(carries(child) for child in rigid.get(link, ()))

    children = [urdf_attribute(j, "child", "link", RobotModelError) for j in joints if j.get("name") in moving]
    return [link for link in children if not carries(link)]


def joint_dynamics(urdf: Path, joints: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """The ``<dynamics damping friction>`` of ``joints`` (in that order) from the URDF: viscous
    damping (N m s/rad or N s/m) and Coulomb friction (N m or N), 0 where not given."""
    by_name = {j.get("name"): j.find("dynamics") for j in _parse(urdf).findall("joint")}
    values = [[float((d.get(key) if d is not None else None) or 0.0) for d in map(by_name.get, joints)]
              for key in ("damping", "friction")]  # fmt: skip
    return np.asarray(values[0]), np.asarray(values[1])


def perturbed_urdf(text: str, frame: str, payload: Payload | None, mass_scale: float) -> str:
    """The URDF ``text`` with every link's mass and inertia scaled by ``mass_scale`` and
    ``payload`` fixed to the link ``frame``: the arm the plant is, not the one the
    controller models."""
    root = ET.fromstring(text)
    for inertial in root.iter("inertial"):
        mass = inertial.find("mass")
        if mass is not None:
            mass.set("value", repr(float(urdf_attribute(mass, ".", "value", RobotModelError)) * mass_scale))
        inertia = inertial.find("inertia")
        if inertia is not None:
            for key, value in inertia.attrib.items():
                inertia.set(key, repr(float(value) * mass_scale))
    if payload is not None:
        link = ET.SubElement(root, "link", name=f"{frame}_payload")
        inertial = ET.SubElement(link, "inertial")
        ET.SubElement(inertial, "origin", xyz=" ".join(map(repr, payload.com)), rpy="0 0 0")
        ET.SubElement(inertial, "mass", value=repr(payload.mass))
        keys = ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")
        ET.SubElement(inertial, "inertia", {k: repr(v) for k, v in zip(keys, payload.inertia, strict=True)})
        joint = ET.SubElement(root, "joint", name=f"{frame}_payload_joint", type="fixed")
        ET.SubElement(joint, "parent", link=frame)
        ET.SubElement(joint, "child", link=f"{frame}_payload")
        ET.SubElement(joint, "origin", xyz="0 0 0", rpy="0 0 0")
    return ET.tostring(root, encoding="unicode")


def frozen_urdf(urdf: Path, joints: list[str]) -> str:
    """The URDF with every movable joint outside ``joints`` (a gripper's fingers, say) fixed at
    zero, as rigid-body data only: no ``mimic`` and ``dynamics`` tags, no top-level elements other
    than links and joints (``material``, ``transmission``, ``ros2_control``, ``gazebo``), no link's
    ``visual`` or ``collision`` (their geometry and materials, which the parser would warn about);
    an ``<inertial>`` or a joint without ``<origin>`` given the identity, which the URDF format
    means by it (the parser requires the element). The arm's dynamics then carry the frozen links
    as rigid loads (the joints that mimic others are in ``joints`` and :class:`Robot` couples them,
    :func:`coupling`)."""
    root = _parse(urdf)
    for child in list(root):
        if child.tag not in ("link", "joint"):
            root.remove(child)
    for link in root.iter("link"):
        for child in [*link.findall("visual"), *link.findall("collision")]:
            link.remove(child)
    for element in [*root.iter("joint"), *root.iter("inertial")]:
        if element.find("origin") is None:
            element.insert(0, ET.Element("origin", xyz="0 0 0", rpy="0 0 0"))
    for joint in root.iter("joint"):
        for tag in ("mimic", "dynamics"):
            for child in joint.findall(tag):
                joint.remove(child)
        if joint.get("name") not in joints and joint.get("type") != "fixed":
            joint.set("type", "fixed")
    return ET.tostring(root, encoding="unicode")


@dataclass
class Robot:
    """An arm with a camera rigidly mounted on the link ``frame``.

    Parameters
    ----------
    urdf
        Path of the URDF.
    frame
        Link carrying the camera.
    mount
        Fixed transform from that link to the camera frame (optical axis = z).
    armature
        Reflected motor inertias added to the diagonal of ``M(q)`` (one per joint), or empty.
    payload, mass_scale
        The arm as it really is, when it differs from the URDF: a body fixed to ``frame``,
        and a factor on every link's mass and inertia (:func:`perturbed_urdf`).
    """

    urdf: Path
    frame: str
    mount: SE3 = field(default_factory=SE3.identity)
    armature: tuple[float, ...] = ()
    payload: Payload | None = None
    mass_scale: float = 1.0

    def __post_init__(self) -> None:
        self.urdf = Path(self.urdf)
        self.joints, self.moving, self.coupling, offset = coupling(
            chain_joints(self.urdf, self.frame), mimic_joints(self.urdf)
        )
        """``joints``: the independent joints of the chain (``q``); ``moving``: every joint the
        dynamics move, ``q_moving = coupling q + offset`` (:func:`coupling`)."""
        joint_limits(self.urdf, self.moving)  # a bad limit is bad input now, not a wrong verdict after a run
        if massless := massless_links(self.urdf, self.moving):
            raise RobotModelError(
                f"{self.urdf.name}: link(s) {', '.join(map(repr, massless))} carry no <inertial> mass or inertia, "
                "nor does anything fixed to them: M(q) would be singular; give each moving link its inertial data"
            )
        if self.armature and len(self.armature) != self.n:
            raise RobotModelError(f"armature: expected {self.n} entries (one per joint), got {len(self.armature)}")
        from adam.casadi import KinDynComputations  # here: imported with scipy's spatial module (0.3-0.5 s)

        try:
            text = frozen_urdf(self.urdf, self.moving)
            if self.perturbed:
                text = perturbed_urdf(text, self.frame, self.payload, self.mass_scale)
            self._kindyn = KinDynComputations(text, self.moving)
        except Exception as exc:  # adam raises bare exceptions on malformed files
            raise RobotModelError(f"cannot build dynamics from {self.urdf.name}: {' '.join(str(exc).split())}") from exc
        try:
            if self.moving == self.joints:
                self.mass_bounds: MassBounds = mass_matrix_bounds(self.urdf, self.joints, self.armature)
                """Bounds on ``M(q)`` for every ``q`` (:mod:`dvfc.models.inertia`; docs/math.md, fact 10)."""
            else:
                arm = np.asarray(self.armature, dtype=float) if self.armature else np.zeros(self.n)
                self.mass_bounds = mass_matrix_bounds(self.urdf, self.moving).coupled(self.coupling, arm)
        except InertiaModelError as exc:
            raise RobotModelError(f"{self.urdf.name}: {exc}") from exc
        self.q = cs.SX.sym("q", self.n)
        self.qd = cs.SX.sym("qd", self.n)
        self._offset = offset
        self._q_moving = cs.DM(self.coupling) @ self.q + cs.DM(offset)

    @property
    def perturbed(self) -> bool:
        """Whether this arm differs from its URDF (a payload or a mass scale)."""
        return self.payload is not None or self.mass_scale != 1.0

    @cached_property
    def limits(self) -> JointLimits:
        """The URDF's limits of the chain's independent joints, the position and velocity limits
        narrowed by those of the joints that mimic them (``lower <= m q_i + o <= upper`` and
        ``|m qd_i| <= velocity`` for ``q_mimic = m q_i + o``)."""
        every = joint_limits(self.urdf, self.moving)
        lower, upper, velocity = (every.lower[: self.n].copy(), every.upper[: self.n].copy(),
                                  every.velocity[: self.n].copy())  # fmt: skip
        for k in range(self.n, len(self.moving)):
            i = int(np.argmax(np.abs(self.coupling[k])))
            m = self.coupling[k, i]
            if m == 0.0:  # a mimic of a joint held fixed: it does not move
                continue
            low, high = sorted(((every.lower[k] - self._offset[k]) / m, (every.upper[k] - self._offset[k]) / m))
            lower[i], upper[i] = max(lower[i], low), min(upper[i], high)
            velocity[i] = min(velocity[i], every.velocity[k] / abs(m))
        return JointLimits(every.effort[: self.n], velocity, lower, upper)

    @property
    def n(self) -> int:
        """Number of joints."""
        return len(self.joints)

    def _joint_block(self, expr: Matrix) -> Matrix:
        """adam models a floating base: keep the joint rows (base fixed at identity)."""
        return expr[6:, 6:] if expr.shape[1] > 1 else expr[6:]

    @cached_property
    def rigid_mass_matrix(self) -> Matrix:
        """The links' part of ``M(q)``: :attr:`mass_matrix` without the :attr:`armature`."""
        t = cs.DM(self.coupling)
        return t.T @ self._joint_block(self._kindyn.mass_matrix(cs.SX.eye(4), self._q_moving)) @ t

    @cached_property
    def mass_matrix(self) -> Matrix:
        """``M(q)`` of (33), symbolic in :attr:`q` (rigid body plus :attr:`armature`)."""
        rigid = self.rigid_mass_matrix
        return rigid + cs.diag(cs.DM(self.armature)) if self.armature else rigid

    @cached_property
    def gravity(self) -> Matrix:
        """``g(q)`` of (33): the gradient of the potential energy."""
        return cs.DM(self.coupling).T @ self._joint_block(self._kindyn.gravity_term(cs.SX.eye(4), self._q_moving))

    @cached_property
    def coriolis(self) -> Matrix:
        """``C(q, qd)`` of (33) from the Christoffel symbols of ``M`` (the reference of :meth:`coriolis_times`,
        which the loop uses, and of the passivity property ``Mdot - 2C`` skew).

        With ``B = d(M qd)/dq`` (``qd`` held fixed), ``C = (Mdot + B - B^T) / 2``; then
        ``C qd`` is the Coriolis and centrifugal torque and ``Mdot - 2C = B^T - B``.
        """
        m = self.mass_matrix
        mdot = cs.reshape(cs.jtimes(cs.vec(m), self.q, self.qd), self.n, self.n)
        b = cs.jacobian(m @ self.qd, self.q)
        return (mdot + b - b.T) / 2

    @cached_property
    def bias(self) -> Matrix:
        """``C(q, qd) qd + g(q)`` of (33) by a recursive Newton-Euler pass (adam's ``bias_force``, the base fixed
        at the identity and at rest): about an eighth of the operations of :attr:`coriolis` times ``qd`` on a
        7-joint arm (docs/math.md, fact 27)."""
        t = cs.DM(self.coupling)
        base = (cs.SX.eye(4), self._q_moving, cs.SX.zeros(6), t @ self.qd)
        return t.T @ self._joint_block(self._kindyn.bias_force(*base))

    @cached_property
    def _velocity_product(self) -> tuple[cs.SX, Matrix]:
        """``(v, C(q, qd) v)`` for a symbol ``v``: the product's operations do not depend on what ``v`` is."""
        v = cs.SX.sym("v", self.n)
        return v, cs.jtimes(self.bias, self.qd, v) / 2

    def coriolis_times(self, v: Matrix) -> Matrix:
        """``C(q, qd) v`` for the Christoffel ``C`` of :attr:`coriolis`, as half the derivative of :attr:`bias`
        along ``v`` in ``qd`` (docs/math.md, fact 27: ``C(q, qd) qd`` is a quadratic form in ``qd`` whose
        symbols are symmetric in its two velocity indices)."""
        symbol, product = self._velocity_product
        return cs.substitute(product, symbol, v)

    @cached_property
    def mass_matrix_dot(self) -> Matrix:
        """``dM/dt = sum_k dM/dq_k qd_k``."""
        return cs.reshape(cs.jtimes(cs.vec(self.mass_matrix), self.q, self.qd), self.n, self.n)

    @cached_property
    def link_pose(self) -> SE3:
        """``g_wl(q)``: world to the link :attr:`frame`, its forward kinematics."""
        return SE3.from_matrix(self._kindyn.forward_kinematics(self.frame, cs.SX.eye(4), self._q_moving))

    @cached_property
    def camera_pose(self) -> SE3:
        """``g_wc(q)``: world to camera, the link's forward kinematics times the mount."""
        return self.link_pose @ self.mount

    @cached_property
    def body_jacobian(self) -> Matrix:
        """``J_b(q)`` with ``V_wc = J_b qd`` (34), ``V_wc = (g_wc^-1 dg_wc/dt)^vee`` (4)."""
        g = self.camera_pose.as_matrix()
        g_inv = self.camera_pose.inverse().as_matrix()
        cols = [vee(g_inv @ cs.reshape(cs.jacobian(cs.vec(g), self.q[i]), 4, 4)) for i in range(self.n)]
        return cs.horzcat(*cols)

    def potential_energy(self) -> Matrix:
        """``U(q) = -m_total g0 . c(q)``, c the centre of mass (for checking ``g(q) = dU/dq``)."""
        com = self._kindyn.CoM_position(cs.SX.eye(4), self._q_moving)
        return -self._kindyn.get_total_mass() * (cs.DM(self._kindyn.g[0:3]).T @ com)

    def function(self, name: str, expr: Matrix) -> cs.Function:
        """A numeric function of ``(q, qd)`` for any of the expressions above."""
        return cs.Function(name, [self.q, self.qd], [expr], ["q", "qd"], [name])
