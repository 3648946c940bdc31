"""Constant bounds on the mass matrix ``M(q)`` of (33), from the URDF (docs/math.md, fact 10).

Every bound here holds for every ``q`` of a serial arm of revolute (or continuous) joints with
unit axes and positive semidefinite link inertias: no joint range enters, and a maximum over
sampled configurations is never used. A file outside these assumptions is refused
(:class:`InertiaModelError`): a prismatic joint in the chain, a joint axis not of unit length
(the dynamics would not be those of a rigid arm), a negative principal inertia on a moved link.

Entrywise upper bound (10.1). ``M = sum_L m_L Jv_L^T Jv_L + Jw_L^T S_L Jw_L`` over the links
``L`` (``S_L`` the link's inertia in the world). Column ``i`` of ``Jw_L`` is the unit axis ``a_i``
and column ``i`` of ``Jv_L`` is ``a_i x (c_L - o_i)``. Let the carrier ``c`` of ``L`` be the last
chain joint above it; frame ``i`` is joint ``i``'s child frame (``o_i`` on the axis, ``a_i`` fixed
in it); ``i'`` is the next chain joint below ``i``. By Cauchy-Schwarz,
``|M_ij| <= B_ij = sum over links moved by i and j of m_L beta_iL beta_jL + alpha_ijL`` with

- ``beta_cL = |a_c x c_L^(c)|`` (exact: the centre of mass is constant in frame ``c``);
- ``beta_iL = |a_i x o_i'^(i)| + l_i'L`` above ``c`` (``o_i'^(i)`` the origin of frame ``i'`` in
  frame ``i``, composed through every fixed joint between them), with the lengths
  ``l_cL = |c_L^(c)|``, ``l_iL = |o_i'^(i)| + l_i'L`` (triangle inequality);
- ``alpha = a_c^T S_L^(c) a_c`` (exact) for ``i = j = c``, ``|S_L^(c) a_c|`` when exactly one of
  ``i, j`` is ``c``, ``lambda_max(I_L)`` otherwise;

plus the armature on the diagonal. The same terms give lower bounds of the diagonal,
``M_ii >= sum_L m_L max(0, |a_i x o_i'^(i)| - l_i'L)^2 + alpha^lo_iiL`` (``beta_cL`` and the
carrier's ``alpha`` exact, ``lambda_min(I_L)`` otherwise).

Matrix upper bound (10.2). For every ``v > 0``, ``x^T M x <= |x|^T B |x| <= x^T D_M(v) x`` with
``D_M(v) = diag((B v)_i / v_i)`` (AM-GM on each product ``|x_i||x_j|``); the scalar bound is
``m_hi = lambda_max(B)`` (Perron-Frobenius: ``rho(M) <= rho(B)``).

Lower bound (10.3). Group the links into the bodies carried by each joint; ``mu_k`` is the
smallest principal inertia of body ``k`` about its centre of mass. The kinetic energy is at
least the rotational part, ``qd^T M qd >= sum_k mu_k |w_k|^2`` with ``w_k - w_(k-1) = a_k qd_k``;
relaxing over every ``w``, for every diagonal ``P >= 0``,
``M(q) >= P / lambda_max(mu^-1/2 Delta^T P Delta mu^-1/2)`` (``Delta`` the first-difference
matrix), plus the armature; 0 when some ``mu_k = 0``. ``P = I`` gives ``m_lo``.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from functools import cached_property, lru_cache
from pathlib import Path

import numpy as np

from dvfc.models.lie import rpy_to_matrix

UPPER_METHOD = (
    "rigorous for every q (docs/math.md, fact 10): |M_ij(q)| <= B_ij from the URDF (Cauchy-Schwarz; "
    "the carrier joint's terms exact, the others by the triangle inequality) plus armature; "
    "M(q) <= D_M(v) = diag(B v / v) for every v > 0"
)
LOWER_METHOD = (
    "rigorous for every q (docs/math.md, fact 10): rotational kinetic energy of the bodies carried by "
    "each joint, sum mu_k |w_k|^2 with w_k - w_(k-1) = a_k qd_k (mu_k the smallest principal inertia): "
    "M(q) >= P / lambda_max(mu^-1/2 Delta^T P Delta mu^-1/2) plus armature"
)
AXIS_TOLERANCE = 1e-12
"""Largest ``| |a| - 1 |`` of a joint axis accepted as a unit axis: a written ``0 0 1`` is exact, and
rounding in a written unit vector is ~1e-16; the bounds then err by at most ~2e-12 relative."""


class InertiaModelError(ValueError):
    """The URDF lies outside the assumptions of the bounds (the message says which, in one line)."""


@dataclass(frozen=True, eq=False)
class MassBounds:
    """Bounds on ``M(q)`` for every ``q`` (module text), all in kg m^2.

    Parameters
    ----------
    upper
        ``B`` (n, n): ``|M_ij(q)| <= B_ij``, symmetric and nonnegative (armature included).
    diagonal_lower
        ``d`` (n,): ``M_ii(q) >= d_i`` (armature included).
    mu
        ``mu_k`` (n,): the smallest principal inertia of the body carried by joint ``k``.
    armature
        The armature added to the diagonal of ``M`` (n,), zeros when none.
    """

    upper: np.ndarray
    diagonal_lower: np.ndarray
    mu: np.ndarray
    armature: np.ndarray
    method_lo: str = LOWER_METHOD
    method_hi: str = UPPER_METHOD

    @cached_property
    def m_hi(self) -> float:
        """``lambda_max(B) >= lambda_max(M(q))`` (the scalar bound)."""
        return float(np.linalg.eigvalsh(self.upper)[-1])

    @cached_property
    def m_lo(self) -> float:
        """``lambda_min`` of :meth:`lower` with ``P = I``: ``<= lambda_min(M(q))``."""
        return float(np.min(np.diag(self.lower())))

    def upper_diagonal(self, v: np.ndarray) -> np.ndarray:
        """``D_M(v) = diag(B v / v)`` for ``v > 0`` (..., n): ``M(q) <= diag(D_M(v))`` (10.2)."""
        v = np.asarray(v, dtype=float)
        return (v @ self.upper) / v  # B is symmetric: (B v)_i = (v B)_i

    def lower(self, p: np.ndarray | None = None) -> np.ndarray:
        """``L_M = P / lambda_max(mu^-1/2 Delta^T P Delta mu^-1/2) + diag(armature) <= M(q)`` (n, n)
        for the diagonal ``P = diag(p) >= 0`` (default ``I``); the rigid part is 0 when some
        ``mu_k = 0`` (a body with no inertia about some axis: no rotation energy to count)."""
        n = len(self.mu)
        p = np.ones(n) if p is None else np.asarray(p, dtype=float)
        rigid = np.zeros(n)
        if np.all(self.mu > 0):
            delta = np.eye(n) - np.eye(n, k=-1)
            scale = 1.0 / np.sqrt(self.mu)
            rigid = p / np.linalg.eigvalsh(scale[:, None] * (delta.T @ (p[:, None] * delta)) * scale[None, :])[-1]
        return np.diag(rigid + self.armature)

    def coupled(self, t: np.ndarray, armature: np.ndarray) -> MassBounds:
        """The bounds on ``T^T M(q) T + diag(armature)``, the mass matrix of the arm whose joints
        move as ``q = T q_r + c`` (mimic joints): ``|T|^T B |T|`` above
        (``|t_i^T M t_j| <= |t_i|^T B |t_j|``), and on the diagonal
        ``t_i^T M t_i >= sum_k t_ki^2 (d_k + B_kk) - |t_i|^T B |t_i|`` (the off-diagonal terms at
        their worst), or 0. ``mu`` is 0: the rotational argument of the lower bound (10.3) needs
        one joint per body, so the rigid part of :meth:`lower` is 0 for the coupled arm.

        Parameters
        ----------
        t
            ``T`` (n_moving, n): the joints of these bounds as functions of the coupled arm's.
        armature
            The coupled arm's armature (n,).
        """
        a = np.abs(np.asarray(t, dtype=float))
        squares = (a**2).T @ (self.diagonal_lower + np.diag(self.upper))
        worst = squares - np.einsum("ki,kl,li->i", a, self.upper, a)
        return MassBounds(
            a.T @ self.upper @ a + np.diag(armature),
            np.maximum(worst, 0.0) + armature,
            np.zeros(a.shape[1]),
            np.asarray(armature, dtype=float),
        )


@dataclass(frozen=True)
class _Link:
    mass: float
    com: np.ndarray  # centre of mass in the link frame
    inertia: np.ndarray  # about the centre of mass, in the link frame


_EMPTY = _Link(0.0, np.zeros(3), np.zeros((3, 3)))


def _vector(element: ET.Element | None, key: str) -> np.ndarray:
    text = None if element is None else element.get(key)
    return np.zeros(3) if not text else np.array([float(v) for v in text.split()])


def urdf_attribute(element: ET.Element, path: str, key: str, error: type[ValueError] = InertiaModelError) -> str:
    """The attribute ``key`` of the element at ``path`` under ``element`` (``"."``: ``element`` itself);
    ``error`` naming them when the URDF lacks either."""
    found = element.find(path)
    value = None if found is None else found.get(key)
    if value is None:
        raise error(f"URDF element <{element.tag} name={element.get('name')!r}> has no {path}/@{key}")
    return value


def _rotation(element: ET.Element | None) -> np.ndarray:
    return np.asarray(rpy_to_matrix(_vector(element, "rpy")), dtype=float)


def _links(root: ET.Element) -> dict[str, _Link]:
    out: dict[str, _Link] = {}
    for link in root.findall("link"):
        inertial = link.find("inertial")
        if inertial is None:
            out[urdf_attribute(link, ".", "name")] = _EMPTY
            continue
        origin, inertia = inertial.find("origin"), inertial.find("inertia")
        i = {k: float(v) for k, v in (inertia.attrib if inertia is not None else {}).items()}
        tensor = np.array([
            [i.get("ixx", 0.0), i.get("ixy", 0.0), i.get("ixz", 0.0)],
            [i.get("ixy", 0.0), i.get("iyy", 0.0), i.get("iyz", 0.0)],
            [i.get("ixz", 0.0), i.get("iyz", 0.0), i.get("izz", 0.0)],
        ])  # fmt: skip
        r = _rotation(origin)
        mass = float(urdf_attribute(inertial, "mass", "value"))
        out[urdf_attribute(link, ".", "name")] = _Link(mass, _vector(origin, "xyz"), r @ tensor @ r.T)
    return out


def _axes(root: ET.Element, joints: list[str]) -> np.ndarray:
    """The unit axes of the chain's joints (n, 3), each in its child frame; a joint that is not
    revolute or continuous, or an axis not of unit length, is refused."""
    by_name = {j.get("name"): j for j in root.findall("joint")}
    axes = []
    for name in joints:
        joint = by_name[name]
        if joint.get("type") not in ("revolute", "continuous"):
            raise InertiaModelError(
                f"joint {name!r} is {joint.get('type')}: the mass-matrix bounds (docs/math.md, fact 10) "
                "cover revolute and continuous joints only"
            )
        element = joint.find("axis")
        axis = np.array([1.0, 0.0, 0.0]) if element is None else _vector(element, "xyz")  # the URDF default
        length = float(np.linalg.norm(axis))
        if abs(length - 1.0) > AXIS_TOLERANCE:
            raise InertiaModelError(
                f"joint {name!r}: axis {' '.join(f'{v:g}' for v in axis)} has length {length:.6g}, not 1 "
                "(the dynamics would not be a rigid arm's): write a unit axis"
            )
        axes.append(axis)
    return np.array(axes)


@dataclass(frozen=True)
class _Carried:
    """Where a link hangs on the chain: its carrier ``c`` (the last chain joint above it), the
    link frame in frame ``c`` (``rotation``, ``translation``) and, for each chain joint ``i``
    above ``c`` (going up), ``(i, o_i'^(i))``: the origin of the next chain joint's frame below
    ``i`` in frame ``i``, composed through the fixed joints between them."""

    carrier: int
    rotation: np.ndarray
    translation: np.ndarray
    above: list[tuple[int, np.ndarray]]


def _carried(name: str, by_child: dict[str, ET.Element], index: dict[str, int]) -> _Carried | None:
    """:class:`_Carried` of the link ``name``; None when no chain joint moves it. Movable joints
    outside the chain count as fixed at zero (as in :func:`dvfc.models.robot.frozen_urdf`)."""
    rotation, translation = np.eye(3), np.zeros(3)  # the tracked frame in the current link's frame
    found: _Carried | None = None
    child = name
    while child in by_child:
        joint = by_child[child]
        origin = joint.find("origin")
        k = index.get(urdf_attribute(joint, ".", "name"))
        if k is not None and found is None:
            found = _Carried(k, rotation, translation, [])
        elif k is not None and found is not None:
            found.above.append((k, translation))
        # across a chain joint only the origin of its frame is tracked (it lies on the axis, so
        # the joint's rotation does not move it): the composed rotation is then unused
        r = _rotation(origin)
        rotation, translation = r @ rotation, r @ translation + _vector(origin, "xyz")
        if k is not None:
            translation = _vector(origin, "xyz")
        child = urdf_attribute(joint, "parent", "link")
    return found


@dataclass(frozen=True)
class _Moved:
    """One link moved by the chain, as the bounds see it: the chain joints moving it (``moved``, the
    carrier first, then the joints above it going up), ``beta_kL`` for each (:func:`_moved_links`; the
    carrier's exact), their lower counterparts, the carrier's axis ``a_c``, the inertia ``S_L^(c)`` in
    the carrier's frame and its principal inertias (ascending)."""

    link: _Link
    moved: list[int]
    beta: list[float]
    beta_lo: list[float]
    axis: np.ndarray
    spin: np.ndarray
    principal: np.ndarray
    rotation: np.ndarray
    translation: np.ndarray


def _lever(axes: np.ndarray, where: _Carried, point: np.ndarray) -> tuple[list[int], list[float], list[float]]:
    """The chain joints moving ``point`` (a point of the link ``where`` describes, in that link's
    frame) and, for each, bounds ``beta_lo <= |a_k x (p - o_k)| <= beta`` for every ``q`` (module
    text: exact for the carrier, the triangle inequality above it)."""
    p = where.rotation @ point + where.translation  # in the carrier's frame
    moved = [where.carrier] + [k for k, _ in where.above]
    beta = [float(np.linalg.norm(np.cross(axes[where.carrier], p)))]
    beta_lo = list(beta)
    length = float(np.linalg.norm(p))
    for k, offset in where.above:
        perpendicular = float(np.linalg.norm(np.cross(axes[k], offset)))
        beta.append(perpendicular + length)
        beta_lo.append(max(0.0, perpendicular - length))
        length += float(np.linalg.norm(offset))
    return moved, beta, beta_lo


def _moved_links(root: ET.Element, joints: list[str]) -> list[_Moved]:
    """Every link the chain ``joints`` moves, as :class:`_Moved` (a negative principal inertia is refused)."""
    by_child = {urdf_attribute(j, "child", "link"): j for j in root.findall("joint")}
    index = {name: k for k, name in enumerate(joints)}
    axes = _axes(root, joints)
    out = []
    for name, link in _links(root).items():
        where = _carried(name, by_child, index)
        if where is None:
            continue
        principal = np.linalg.eigvalsh(link.inertia)
        if principal[0] < -AXIS_TOLERANCE * max(1.0, principal[-1]):
            raise InertiaModelError(
                f"link {name!r}: principal inertia {principal[0]:.6g} kg m^2 < 0 (not a rigid body): "
                "the mass-matrix bounds need positive semidefinite link inertias"
            )
        moved, beta, beta_lo = _lever(axes, where, link.com)
        spin = where.rotation @ link.inertia @ where.rotation.T  # S_L^(c)
        out.append(_Moved(link, moved, beta, beta_lo, axes[where.carrier], spin, principal, where.rotation,
                          where.translation))  # fmt: skip
    return out


def mass_matrix_bounds(urdf: str | Path, joints: list[str], armature: tuple[float, ...] = ()) -> MassBounds:
    """The bounds of the module text for the arm whose chain joints are ``joints`` (root first;
    every other movable joint frozen at zero, as in :func:`dvfc.models.robot.frozen_urdf`, and
    each joint moving on its own: the bounds of an arm with mimic joints are those of this one
    through :meth:`MassBounds.coupled`).

    Raises
    ------
    InertiaModelError
        A chain joint not revolute or continuous, an axis not of unit length, or a link moved by
        the chain with a negative principal inertia.
    """
    return _bounds(Path(urdf).read_bytes(), tuple(joints), tuple(float(a) for a in armature))


@lru_cache(maxsize=16)
def _bounds(urdf: bytes, joints: tuple[str, ...], armature: tuple[float, ...]) -> MassBounds:
    """:func:`mass_matrix_bounds` of a URDF's text, computed once for each text, chain and armature (a case is
    built anew for each candidate design, campaign draw and margin point, on the same arm); its arrays read-only,
    as every arm built on them shares them."""
    root = ET.fromstring(urdf)
    n = len(joints)
    arm = np.asarray(armature, dtype=float) if armature else np.zeros(n)
    upper, lower = np.diag(arm), arm.copy()
    bodies = [_EMPTY] * n
    for item in _moved_links(root, list(joints)):
        moved, beta, a, spin = item.moved, item.beta, item.axis, item.spin
        alpha = np.full((len(moved), len(moved)), item.principal[-1])
        alpha[0, :] = alpha[:, 0] = np.linalg.norm(spin @ a)  # |a_i^T S a_c| <= |S a_c|
        alpha[0, 0] = a @ spin @ a  # exact
        upper[np.ix_(moved, moved)] += item.link.mass * np.outer(beta, beta) + alpha
        lower[moved] += item.link.mass * np.square(item.beta_lo) + np.r_[a @ spin @ a,
                                                                         np.full(len(moved) - 1, item.principal[0])]
        bodies[moved[0]] = _merge(bodies[moved[0]], item.link, item.rotation, item.translation)
    mu = np.maximum([np.linalg.eigvalsh(body.inertia)[0] for body in bodies], 0.0)
    for array in (upper, lower, mu, arm):
        array.setflags(write=False)
    return MassBounds(upper, lower, mu, arm)


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


@dataclass(frozen=True)
class CoriolisBounds:
    """Bounds on the Christoffel symbols of ``M(q)`` for every ``q`` (docs/math.md, fact 23, (B1)):
    ``|Gamma_ijk(q)| <= G_ijk`` with ``C(q, qd)_ij = sum_k Gamma_ijk qd_k``; per row
    ``|(C(q, qd) b)_i| <= rows_i |qd| |b|`` (``rows_i = ||G[i]||_2``), as a whole
    ``|a^T C(q, qd) b| <= whole |a| |b| |qd|`` (the smallest spectral norm of ``G``'s unfoldings)."""

    tensor: np.ndarray
    rows: np.ndarray
    whole: float


def christoffel_bounds(urdf: str | Path, joints: list[str]) -> CoriolisBounds:
    """(B1) of docs/math.md, fact 23: for each link ``L`` moved by ``i``, ``j`` and ``k``
    (``lo, hi = min, max(i, j)``), ``|dM_ij/dq_k| <= E_ijk``, the sum over links of 0 for ``k <= lo``,
    ``m_L (beta_k beta_hi + beta_lo beta_hi) + lambda_max(I_L)`` for ``lo < k <= hi`` and
    ``m_L (beta_k beta_hi + beta_lo beta_k) + lambda_max(I_L) - lambda_min(I_L)`` for ``k > hi``
    (turning joint ``k`` moves the part distal to it rigidly about its axis); then
    ``G_ijk = (E_ijk + E_ikj + E_jki) / 2``. The armature is constant and adds nothing."""
    root = ET.parse(urdf).getroot()
    n = len(joints)
    e = np.zeros((n, n, n))
    for item in _moved_links(root, joints):
        beta = dict(zip(item.moved, item.beta, strict=True))
        mass, top, bottom = item.link.mass, item.principal[-1], item.principal[0]
        for i in item.moved:
            for j in item.moved:
                lo, hi = min(i, j), max(i, j)
                for k in item.moved:
                    if lo < k <= hi:
                        e[i, j, k] += mass * (beta[k] * beta[hi] + beta[lo] * beta[hi]) + top
                    elif k > hi:
                        e[i, j, k] += mass * (beta[k] * beta[hi] + beta[lo] * beta[k]) + top - bottom
    g = (e + e.transpose(0, 2, 1) + e.transpose(2, 1, 0)) / 2  # E_ijk + E_ikj + E_jki (E symmetric in i, j)
    rows = np.array([np.linalg.norm(g[i], 2) for i in range(n)])
    whole = min(float(np.linalg.norm(g.transpose(axes).reshape(n, n * n), 2))
                for axes in ((0, 1, 2), (1, 0, 2), (2, 0, 1)))  # fmt: skip
    return CoriolisBounds(g, rows, whole)


def camera_levers(urdf: str | Path, joints: list[str], frame: str, mount: np.ndarray) -> np.ndarray:
    """(B2) of docs/math.md, fact 23: ``d_i >= dist(camera origin, axis i)`` for every ``q``, the
    length of the linear part of column ``i`` of ``J_b`` (its angular part is a unit axis). The
    camera origin is the point ``mount`` of the link ``frame`` (its frame); 0 for a joint that
    does not move it."""
    root = ET.parse(urdf).getroot()
    by_child = {urdf_attribute(j, "child", "link"): j for j in root.findall("joint")}
    where = _carried(frame, by_child, {name: k for k, name in enumerate(joints)})
    d = np.zeros(len(joints))
    if where is not None:
        moved, beta, _ = _lever(_axes(root, joints), where, np.asarray(mount, dtype=float))
        d[moved] = beta
    return d
