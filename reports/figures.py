"""Figures of a design review, drawn with matplotlib and returned as inline SVG.

Colours are fixed across figures: the control error and the camera in blue, the
estimation error and the target in orange, the certificate's bound in green, the
quantity it bounds in red; vector components keep one colour each (x, y, z).
"""

from __future__ import annotations

import io

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.colors import LogNorm
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle

from dvfc.analysis.grid import GainMap
from dvfc.analysis.simulate import Trajectory

CONTROL, ESTIMATE, BOUND, BOUNDED = "#1f77b4", "#ff7f0e", "#2ca02c", "#d62728"
COMPONENTS = ("#1f77b4", "#d62728", "#2ca02c")
"""Colours of the x, y, z components (and of the rotation-error components 1, 2, 3)."""

plt.rcParams.update({
    "font.size": 9, "axes.grid": True, "grid.alpha": 0.3, "legend.fontsize": 8, "svg.fonttype": "none",
    "figure.dpi": 100,
})  # fmt: skip


def svg(fig: Figure) -> str:
    """The figure as an ``<svg>`` element (no XML prolog; its size in pt, so every figure
    shares one font scale)."""
    buffer = io.StringIO()
    fig.savefig(buffer, format="svg", bbox_inches="tight", dpi=150)  # dpi: rasterised parts (the map)
    plt.close(fig)
    text = buffer.getvalue()
    return text[text.index("<svg") :]


def _translation(vec_pose: np.ndarray) -> np.ndarray:
    """Positions from column-major vectorised 4x4 poses ``(T, 16)``."""
    return vec_pose[:, 12:15]


def paths(traj: Trajectory) -> str:
    """Camera and target positions in the world frame (3D)."""
    fig = plt.figure(figsize=(6.4, 4.6))
    ax = fig.add_subplot(projection="3d")
    for name, signal, colour in (("camera", "g_wc", CONTROL), ("target", "g_wo", ESTIMATE)):
        p = _translation(traj[signal])
        ax.plot(*p.T, color=colour, label=f"{name} path")
        ax.scatter(*p[0], color=colour, marker="o", s=20, label=f"{name} at t = 0")
        ax.scatter(*p[-1], color=colour, marker="s", s=20, label=f"{name} at t = {traj.t[-1]:.3g} s")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_zlabel("z [m]")
    ax.set_title("Camera and target in the world frame")
    ax.legend(loc="upper left", bbox_to_anchor=(1.05, 1.0))
    return svg(fig)


def image_plane(traj: Trajectory, focal_length: float) -> str:
    """Feature points in the image plane: actual ``f`` and estimated ``fbar`` (14), (18)."""
    fig, ax = plt.subplots(figsize=(6.0, 4.8))
    f, fbar = traj["f"], traj["fbar"]
    for i in range(f.shape[1] // 2):
        first = i == 0
        ax.plot(f[:, 2 * i], f[:, 2 * i + 1], color=CONTROL, label="actual f" if first else None)
        ax.plot(fbar[:, 2 * i], fbar[:, 2 * i + 1], "--", color=ESTIMATE, label="estimated fbar" if first else None)
        ax.plot(*f[0, 2 * i : 2 * i + 2], "o", color=CONTROL, ms=4, label="t = 0" if first else None)
        ax.plot(*f[-1, 2 * i : 2 * i + 2], "s", color=CONTROL, ms=4, label="final" if first else None)
        ax.annotate(f"{i + 1}", (f[-1, 2 * i], f[-1, 2 * i + 1]), textcoords="offset points", xytext=(5, 5))
    ax.set_xlabel("image x [px]")
    ax.set_ylabel("image y [px]")
    ax.set_title(f"Feature points (focal length {focal_length:g} px)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.legend()
    return svg(fig)


def envelope_image(traj: Trajectory, centre: np.ndarray, size: tuple[float, float], envelope: dict) -> str:
    """The image (its border), the certified feature regions of docs/math.md, facts 8 and 16.0 (boxes at the
    certified level, and at the ultimate level ``c_inf``) and the simulated feature tracks."""
    fig, ax = plt.subplots(figsize=(6.0, 5.0))
    width, height = size
    view = np.array([-0.05 * width, -0.05 * height, 1.05 * width, 1.05 * height])
    notes = []
    for name, style, kind, level in (("boxes_px", "-", "certified region", "V <= c"),
                                     ("ultimate_boxes_px", ":", "ultimate region", "V <= c_inf")):  # fmt: skip
        boxes = np.asarray(envelope.get(name) or [], dtype=float).reshape(-1, 4)
        shown = np.concatenate([np.maximum(boxes[:, :2], view[:2]), np.minimum(boxes[:, 2:], view[2:])], axis=1)
        drawn = shown[(shown[:, 2] > shown[:, 0]) & (shown[:, 3] > shown[:, 1])]
        for i, (u0, v0, u1, v1) in enumerate(drawn):
            ax.add_patch(Rectangle((u0, v0), u1 - u0, v1 - v0, fill=True, alpha=0.12, color=BOUND, ls=style, lw=1.5,
                                   label=f"{kind} ({level})" if i == 0 else None))  # fmt: skip
        if len(drawn) < len(boxes):
            notes.append(f"{len(boxes) - len(drawn)} of {len(boxes)} {kind}s lie wholly outside the view")
        elif np.any(shown != boxes):
            notes.append(f"the {kind}s extend beyond the view: drawn clipped to it")
    if notes and envelope.get("image_margin_px") is not None:
        notes.append(f"image margin {envelope['image_margin_px']:.4g} px: visibility not certified")
    if notes:
        ax.text(0.5, 0.02, "\n".join(notes), transform=ax.transAxes, ha="center", va="bottom", fontsize=7,
                bbox={"facecolor": "white", "alpha": 0.8, "edgecolor": "none"})  # fmt: skip
    _tracks_in_image(ax, traj, centre, size, "Certified feature regions (facts 8, 16.0) and the simulated tracks")
    return svg(fig)


def implemented_image(
    traj: Trajectory,
    centre: np.ndarray,
    size: tuple[float, float],
    title: str = "Features of the run as implemented, in the image",
    pixels: np.ndarray | None = None,
) -> str:
    """The feature tracks of a run as implemented inside the image border (pixels): the model's
    features about ``centre``, or ``pixels`` (``(T, m, 2)``, from the top-left corner) when given
    (the plant's camera, :func:`dvfc.analysis.campaign.true_pixels`)."""
    fig, ax = plt.subplots(figsize=(6.0, 5.0))
    _tracks_in_image(ax, traj, centre, size, title, pixels)
    return svg(fig)


def _tracks_in_image(ax, traj: Trajectory, centre: np.ndarray, size: tuple[float, float], title: str,
                     pixels: np.ndarray | None = None) -> None:  # fmt: skip
    """The image border and the simulated feature tracks, in pixels (rows downwards): the
    model's features about ``centre``, or ``pixels`` when given."""
    width, height = size
    ax.add_patch(Rectangle((0, 0), width, height, fill=False, color="black", lw=1.5, label="image border"))
    f = traj["f"].reshape(len(traj.t), -1, 2) + centre if pixels is None else pixels
    for i in range(f.shape[1]):
        ax.plot(f[:, i, 0], f[:, i, 1], color=BOUNDED, lw=1, label="simulated features" if i == 0 else None)
        ax.plot(*f[0, i], "o", color=BOUNDED, ms=3)
    ax.set_xlim(-0.05 * width, 1.05 * width)
    ax.set_ylim(1.05 * height, -0.05 * height)  # image rows grow downwards
    ax.set_aspect("equal")
    ax.set_xlabel("u [px]")
    ax.set_ylabel("v [px]")
    ax.set_title(title)
    ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0))


def errors(traj: Trajectory) -> str:
    """Components of the control error ``e_c`` (8) and the estimation error ``e_e`` (15):
    position and rotation parts, or the position alone for the planar loop."""
    parts = (("position", "m", "p"), ("rotation", "-", "e_R"))[: 2 if traj["e_c"].shape[1] == 6 else 1]
    fig, axes = plt.subplots(2, len(parts), figsize=(3.5 * len(parts), 5.6), sharex=True, squeeze=False)
    for row, (name, label) in enumerate((("e_c", "control error e_c"), ("e_e", "estimation error e_e"))):
        e = traj[name]
        for col, (part, unit, symbol) in enumerate(parts):
            ax = axes[row, col]
            for k in range(min(3, e.shape[1])):
                ax.plot(traj.t, e[:, 3 * col + k], color=COMPONENTS[k], label=f"{symbol}_{'xyz'[k]}")
            ax.set_title(f"{label}: {part}")
            ax.set_ylabel(f"{part} [{unit}]")
            ax.legend(ncol=3)
    for ax in axes[1]:
        ax.set_xlabel("time [s]")
    fig.tight_layout()
    return svg(fig)


def storage(traj: Trajectory) -> str:
    """The storage function ``V`` (38) along the run."""
    fig, ax = plt.subplots(figsize=(6.0, 3.4))
    ax.semilogy(traj.t, np.maximum(traj["V"][:, 0], np.finfo(float).tiny), color=CONTROL, label="V(t)")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("V [J] (kinetic energy + weighted pose errors)")
    ax.set_title("Storage function V (38)")
    ax.legend()
    return svg(fig)


def torques(traj: Trajectory) -> str:
    """Joint torques ``tau`` (35)."""
    fig, ax = plt.subplots(figsize=(6.0, 3.4))
    tau = traj["tau"]
    colours = plt.get_cmap("tab10")
    for j in range(tau.shape[1]):
        ax.plot(traj.t, tau[:, j], color=colours(j), label=f"joint {j + 1}")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("torque [N m]")
    ax.set_title("Joint torques tau (35)")
    ax.legend(ncol=min(tau.shape[1], 4))
    return svg(fig)


def supply(traj: Trajectory) -> str:
    """Lemma 2 on the run shown, with ``w``: ``V(t) - V(0) = int u^T nu + int x^T G w``
    ((40)-(41)), hence ``>= -V(0)`` as ``V >= 0``; ``int u^T nu`` alone, whose bound
    ``>= -V(0)`` (37) is stated for ``w = 0``."""
    fig, ax = plt.subplots(figsize=(6.0, 3.4))
    v, i = traj["V"][:, 0], traj.integrals
    ax.plot(traj.t, i["supply_u_nu"] + i["supply_x_G_w"], color=BOUNDED, label="int_0^t (u^T nu + x^T G w) dt")
    ax.plot(traj.t, v - v[0], color="k", ls=":", label="V(t) - V(0)")
    ax.plot(traj.t, i["supply_u_nu"], color=ESTIMATE, lw=0.8, label="int_0^t u^T nu dt (>= -V(0) when w = 0)")
    ax.axhline(-v[0], color=BOUND, ls="--", label="-V(0)")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("supplied energy [J]")
    ax.set_title("Lemma 2: V(t) - V(0) = int u^T nu + int x^T G w >= -V(0)")
    ax.legend(fontsize=7)
    return svg(fig)


def l2_inequality(traj: Trajectory, gamma: float) -> str:
    """Both sides of (45) over time: ``int |x|^2`` and ``gamma^2 int |w|^2 + 2 V(0)``."""
    fig, ax = plt.subplots(figsize=(6.0, 3.4))
    left = traj.integrals["z_squared"]
    right = gamma**2 * traj.integrals["d_squared"] + 2 * traj["V"][0, 0]
    ax.semilogy(traj.t[1:], left[1:], color=BOUNDED, label="int_0^t |x|^2 dt")
    ax.semilogy(traj.t, right, color=BOUND, ls="--", label=f"gamma^2 int_0^t |w|^2 dt + 2 V(0), gamma = {gamma:.4g}")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("integral [-]")
    ax.set_title("Theorem 2: L2-gain inequality (45)")
    ax.legend()
    return svg(fig)


MAP_LABELS = {
    "gamma": ("certified gamma [-]", "Theorem 2: certified gamma over the gains", "viridis_r"),
    "rate": ("certified decay rate kappa [1/s]", "Fact 7: certified decay rate over the gains", "viridis"),
    "max_target_speed": ("largest target speed, features certified in view [m/s]",
                         "Facts 7-8: largest target speed kept in view over the gains", "viridis"),
}  # fmt: skip
"""Per quantity of a :class:`GainMap`: axis label, title, colour map (dark = better)."""


def gain_map(m: GainMap, design: dict[str, float]) -> str:
    """The map's quantity (certified gamma, or an envelope column) over its axes, the certified
    region outlined, the scenario's design marked (``design`` holds its value on each axis and
    on the quantity)."""
    label, title, cmap = MAP_LABELS[m.quantity]
    fig, ax = plt.subplots(figsize=(6.0, 4.6))
    values = m.shown()
    shown = np.isfinite(values)
    if m.y_axis is None:
        ax.plot(m.x, values[0], color=BOUND, label=label.split(" [")[0])
        ax.set_ylabel(label)
        ax.set_yscale("log")
        marker = (design[m.x_axis], design[m.quantity])
    else:
        finite = values[shown]
        norm = LogNorm(finite.min(), finite.max()) if finite.size and finite.max() > finite.min() else None
        mesh = ax.pcolormesh(m.x, m.y, values, shading="nearest", cmap=cmap, norm=norm, rasterized=True)
        fig.colorbar(mesh, ax=ax, label=f"{label} (blank: not certified)")
        if shown.any() and not shown.all():
            ax.contour(m.x, m.y, shown.astype(float), levels=[0.5], colors="k", linewidths=1.5)
            ax.plot([], [], color="k", label="edge of the certified region")
        ax.set_ylabel(f"{m.y_axis} [-]")
        ax.set_yscale("log" if _spread(m.y) else "linear")
        marker = (design[m.x_axis], design[m.y_axis])
    ax.plot(*marker, "r*", ms=12, label="scenario's design")
    ax.set_xscale("log" if _spread(m.x) else "linear")
    ax.set_xlabel(f"{m.x_axis} [-]")
    ax.set_title(title)
    ax.legend(loc="upper right")
    return svg(fig)


def _spread(values: np.ndarray) -> bool:
    """Whether positive ``values`` span more than a decade (then a log axis reads better)."""
    return bool(values.min() > 0 and values.max() / values.min() > 10)


def campaign_ecdf(runs: dict, tolerance: dict) -> str:
    """The empirical distribution of a campaign's tracking ratio (the tracking error over the
    criterion's bound, the larger of position and angle; 1 is the bound), the bound and the
    tolerance bound's order statistic; runs that did not complete sit beyond the right edge."""
    ratio = np.asarray(runs["tracking_ratio"], dtype=float)
    done = np.isfinite(ratio) & (np.asarray(runs["status"]) == "ok")
    x = np.sort(ratio[done])
    fig, ax = plt.subplots(figsize=(6.4, 3.4))
    ax.step(x, np.arange(1, len(x) + 1) / len(ratio), where="post", color=CONTROL,
            label=f"runs ({len(ratio) - len(x)} not completed: beyond the right edge)")  # fmt: skip
    ax.axvline(1.0, color=BOUNDED, lw=1.5, label="criterion's tracking bound")
    if tolerance.get("rank") is not None and np.isfinite(tolerance["tracking_ratio"]):
        ax.axvline(tolerance["tracking_ratio"], color=BOUND, ls="--",
                   label=f"tolerance bound: rank {tolerance['rank']} of {len(ratio)}")  # fmt: skip
    ax.set_xlabel("tracking error / bound (max of position and angle)")
    ax.set_ylabel("fraction of runs")
    ax.set_ylim(0, 1.02)
    ax.legend(loc="lower right")
    return svg(fig)


def campaigns_ecdf(designs: dict[str, dict]) -> str:
    """The empirical distributions of the closeness to failing (the largest of the tracking ratio
    and the peak limit ratios; above 1 a run fails) of campaigns of several designs, by label, on
    the same runs (the same seeds: common random numbers); runs that did not complete sit beyond
    the right edge."""
    fig, ax = plt.subplots(figsize=(6.4, 3.4))
    for (label, runs), colour in zip(designs.items(), (BOUNDED, CONTROL, ESTIMATE, BOUND), strict=False):
        closeness = np.asarray(runs["closeness"], dtype=float)
        done = np.isfinite(closeness) & (np.asarray(runs["status"]) == "ok")
        failed = int((~np.asarray(runs["holds"], dtype=bool)).sum())
        x = np.sort(closeness[done])
        ax.step(x, np.arange(1, len(x) + 1) / len(closeness), where="post", color=colour,
                label=f"{label}: {failed} of {len(closeness)} fail")  # fmt: skip
    ax.axvline(1.0, color="black", lw=1.0, ls="--", label="fails beyond 1")
    ax.set_xlabel("closeness to failing (max of tracking / bound and peak / limit ratios)")
    ax.set_ylabel("fraction of runs")
    ax.set_ylim(0, 1.02)
    ax.legend(loc="lower right")
    return svg(fig)


def sensitivity_bars(sensitivity: list[dict], floor: float | None) -> str:
    """Each drawn quantity's PAWN score (its strongest entry; the closeness to failing), strongest
    on top, with the floor of the independent reference inputs."""
    known = [e for e in sensitivity if e["pawn"] is not None]
    fig, ax = plt.subplots(figsize=(6.4, 0.35 * len(known) + 1.0))
    score = np.array([e["pawn"] for e in known])
    above = np.array([bool(e["above_floor"]) for e in known])
    ax.barh(np.arange(len(known)), score, color=np.where(above, BOUNDED, CONTROL))
    ax.set_yticks(np.arange(len(known)), [e["column"] for e in known])
    ax.invert_yaxis()
    if floor is not None:
        ax.axvline(floor, color="black", lw=0.8, ls="--", label="floor (independent inputs)")
        ax.legend(loc="lower right")
    ax.set_xlim(0, 1)
    ax.set_xlabel("PAWN: largest KS distance of the closeness to failing over slices")
    return svg(fig)


def drivers_scatter(runs: dict, sensitivity: list[dict]) -> str:
    """Each run at the values of the two strongest drivers (their strongest entries; with one
    drawn quantity, it against the tracking ratio), the runs that fail marked."""
    x_name = sensitivity[0]["column"]
    y_name = sensitivity[1]["column"] if len(sensitivity) > 1 else "tracking_ratio"
    x, y = np.asarray(runs[x_name], dtype=float), np.asarray(runs[y_name], dtype=float)
    holds = np.asarray(runs["holds"], dtype=bool)
    fig, ax = plt.subplots(figsize=(6.0, 4.4))
    ax.scatter(x[holds], y[holds], s=10, color=CONTROL, label=f"holds ({holds.sum()})")
    ax.scatter(x[~holds], y[~holds], s=28, marker="x", color=BOUNDED, label=f"fails ({(~holds).sum()})")
    ax.set_xlabel(x_name)
    ax.set_ylabel(y_name)
    ax.legend(loc="best")
    return svg(fig)
