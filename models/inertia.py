"""Rigorous bounds on the eigenvalues of the mass matrix ``M(q)`` of (33), from the URDF.

MATH fact 7 needs ``m_hi >= lambda_max(M(q))`` and ``m_lo <= lambda_min(M(q))`` for
every configuration the run can reach; a maximum over sampled configurations is not a
bound. Both numbers here hold for every ``q`` of an arm of revolute joints (no joint
range enters) and come from the URDF's masses, inertias and joint offsets alone.

Upper bound. ``M = sum_L m_L Jv_L^T Jv_L + Jw_L^T R_L I_L R_L^T Jw_L`` over the links
``L``. For a revolute joint ``i`` that moves ``L``, ``Jw_L`` column ``i`` is the unit axis
``a_i`` and ``Jv_L`` column ``i`` is ``a_i x (c_L - o_i)``, of length at most
``r_iL >= |c_L - o_i|``: the sum of the lengths of the fixed offsets from joint ``i``'s
origin to ``L``'s centre of mass (triangle inequality). By Cauchy-Schwarz
``|M_ij| <= B_ij = sum_L (m_L r_iL r_jL + lambda_max(I_L))`` (the sum over links moved by
both joints), plus the armature on the diagonal. Since ``|M| <= B`` entrywise and ``B``
is symmetric and nonnegative, ``lambda_max(M) <= rho(M) <= rho(B) = lambda_max(B)``
(Perron-Frobenius; Horn and Johnson, Theorem 8.1.18). A prismatic joint ``i`` has
``|Jv| = 1`` and lengthens the offsets of the links after it by at most its largest
``|limit|``.

Lower bound. Group the links into the bodies ``b_k`` carried by joint ``k`` (rigid to
one another); ``mu_k = lambda_min`` of ``b_k``'s inertia about its centre of mass. The
kinetic energy is at least the rotational part, ``qd^T M qd >= sum_k mu_k |w_k|^2`` with
the angular velocities ``w_k = w_{k-1} + a_k qd_k``, so ``|qd_k| = |w_k - w_{k-1}|`` and,
over all ``w`` (a relaxation), ``qd^T M qd >= |qd|^2 / lambda_max(mu^-1/2 D^T D mu^-1/2)``
with ``D`` the first-difference matrix. The armature adds its smallest entry. Zero when a
body has a zero principal inertia or a joint is prismatic (no rotation to count).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dvfc.models.lie import rpy_to_matrix

HI_METHOD = (
    "rigorous upper bound for every q: lambda_max(B) with |M_ij(q)| <= B_ij = sum over links of "
    "m r_i r_j + lambda_max(I) (Cauchy-Schwarz; r from the URDF's offsets by the triangle inequality; "
    "rho(M) <= rho(B), Perron-Frobenius) plus armature"
)
LO_METHOD = (
    "rigorous lower bound for every q: rotational kinetic energy of the bodies carried by each joint, "
    "sum mu_k |w_k|^2 with w_k - w_{k-1} = a_k qd_k (mu_k = smallest principal inertia), plus the "
    "smallest armature"
)


@dataclass(frozen=True)
class MassBounds:
    """``m_lo <= lambda_min(M(q))`` and ``lambda_max(M(q)) <= m_hi`` for every ``q``."""

    m_lo: float
    m_hi: float
    method_lo: str = LO_METHOD
    method_hi: str = HI_METHOD


@dataclass(frozen=True)
class _Link:
    mass: float
    com: np.ndarray  # centre of mass in the link frame
    inertia: np.ndarray  # about the centre of mass, in the link frame


def _vector(element: ET.Element | None, key: str) -> np.ndarray:
    text = None if element is None else element.get(key)
    return np.zeros(3) if not text else np.array([float(v) for v in text.split()])


def _rotation(element: ET.Element | None) -> np.ndarray:
    return np.asarray(rpy_to_matrix(_vector(element, "rpy")), dtype=float)


def _links(root: ET.Element) -> dict[str, _Link]:
    out = {}
    for link in root.findall("link"):
        inertial = link.find("inertial")
        if inertial is None:
            out[link.get("name")] = _Link(0.0, np.zeros(3), np.zeros((3, 3)))
            continue
        origin = inertial.find("origin")
        i = {k: float(v) for k, v in inertial.find("inertia").attrib.items()}
        tensor = np.array([
            [i.get("ixx", 0.0), i.get("ixy", 0.0), i.get("ixz", 0.0)],
            [i.get("ixy", 0.0), i.get("iyy", 0.0), i.get("iyz", 0.0)],
            [i.get("ixz", 0.0), i.get("iyz", 0.0), i.get("izz", 0.0)],
        ])  # fmt: skip
        r = _rotation(origin)
        mass = float(inertial.find("mass").get("value"))
        out[link.get("name")] = _Link(mass, _vector(origin, "xyz"), r @ tensor @ r.T)
    return out


def mass_matrix_bounds(urdf: str | Path, joints: list[str], armature: tuple[float, ...] = ()) -> MassBounds:
    """``m_lo``, ``m_hi`` of the arm whose movable joints are ``joints`` (root first; every
    other movable joint frozen at zero, as in :func:`dvfc.models.robot.frozen_urdf`). See the
    module text. A joint axis not of unit length counts with the worse of 1 and its length."""
    root = ET.parse(urdf).getroot()
    by_child = {j.find("child").get("link"): j for j in root.findall("joint")}
    chain = {j.get("name"): j for j in root.findall("joint") if j.get("name") in joints}
    axis = np.array([np.linalg.norm(_vector(chain[name].find("axis"), "xyz")) or 1.0 for name in joints])
    prismatic = np.array([chain[name].get("type") == "prismatic" for name in joints])
    index = {name: k for k, name in enumerate(joints)}
    n = len(joints)
    b = np.diag(np.asarray(armature, dtype=float)) if armature else np.zeros((n, n))
    bodies = [_Link(0.0, np.zeros(3), np.zeros((3, 3))) for _ in range(n)]
    for name, link in _links(root).items():
        linear, angular = np.zeros(n), np.zeros(n)  # bounds on |Jv_L| and |Jw_L| column by column
        length = np.linalg.norm(link.com)  # >= distance from the current joint's origin to the centre of mass
        rotation, translation = np.eye(3), np.zeros(3)  # the link's frame in its carrying joint's frame
        carrier, child = None, name
        while child in by_child:
            joint = by_child[child]
            offset = _vector(joint.find("origin"), "xyz")
            k = index.get(joint.get("name"))
            if k is None and carrier is None:
                r = _rotation(joint.find("origin"))
                rotation, translation = r @ rotation, r @ translation + offset
            elif k is not None:
                carrier = k if carrier is None else carrier
                scale = max(1.0, axis[k])
                if prismatic[k]:
                    limit = joint.find("limit")
                    bounds = (limit.get("lower", "inf"), limit.get("upper", "inf")) if limit is not None else ("inf",)
                    linear[k] = scale
                    length += max(abs(float(v)) for v in bounds) * scale
                else:
                    linear[k], angular[k] = scale * length, scale
            length += np.linalg.norm(offset)
            child = joint.find("parent").get("link")
        if carrier is None:
            continue
        b += link.mass * np.outer(linear, linear) + np.linalg.eigvalsh(link.inertia)[-1] * np.outer(angular, angular)
        bodies[carrier] = _merge(bodies[carrier], link, rotation, translation)
    mu = np.array([np.linalg.eigvalsh(body.inertia)[0] for body in bodies])
    rigid = 0.0
    if not prismatic.any() and np.all(mu > 0):
        # |qd_k| = |w_k - w_{k-1}| / |a_k| <= |w_k - w_{k-1}| / min(1, |a_k|)
        d = (np.eye(n) - np.eye(n, k=-1)) / np.minimum(1.0, axis)[:, None]
        s = 1.0 / np.sqrt(mu)
        rigid = float(1.0 / np.linalg.eigvalsh(s[:, None] * (d.T @ d) * s[None, :])[-1])
    return MassBounds(rigid + (min(armature) if armature else 0.0), float(np.linalg.eigvalsh(b)[-1]))


def _merge(body: _Link, link: _Link, rotation: np.ndarray, translation: np.ndarray) -> _Link:
    """The composite of two rigidly attached bodies (``link`` placed by ``rotation``,
    ``translation`` in the body's frame): mass, centre of mass, inertia about it
    (parallel-axis theorem)."""
    com = rotation @ link.com + translation
    inertia = rotation @ link.inertia @ rotation.T
    mass = body.mass + link.mass
    if mass == 0.0:
        return _Link(0.0, np.zeros(3), body.inertia + inertia)
    centre = (body.mass * body.com + link.mass * com) / mass
    total = np.zeros((3, 3))
    for m, c, i in ((body.mass, body.com, body.inertia), (link.mass, com, inertia)):
        d = c - centre
        total += i + m * (d @ d * np.eye(3) - np.outer(d, d))
    return _Link(mass, centre, total)
