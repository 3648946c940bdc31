"""``[dispersion]``: a distribution for each uncertain quantity of the loop as implemented, keyed by
the field it perturbs, drawn once per campaign run.

Each distribution describes the deviation from the scenario's value of its field (its default
when absent; for ``plant.camera.*`` the controller's ``[camera]`` value, for ``plant.mount`` no
error): ``normal`` adds ``N(0, sigma)`` (redrawn beyond ``clip`` sigmas when ``clip`` is
given), ``uniform`` adds ``U(low, high)``, ``lognormal`` multiplies by ``exp(N(0, sigma))``,
``choice`` takes one of ``values`` (absolute). A value outside its field's domain (a negative
latency, a probability above 1) is clipped to it. Only fields that are inputs of the compiled
loop (:data:`FIELDS`) can be dispersed, so that no run recompiles: the target's radius and the
plant's masses are entries of its parameter vector (:class:`dvfc.analysis.parametric.Inputs`).
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from dvfc.analysis.parametric import Inputs
from dvfc.analysis.schema import DistributionSection, Scenario, ScenarioError
from dvfc.analysis.simulate import Settings
from dvfc.analysis.start import image_start
from dvfc.models.lie import SE3
from dvfc.models.loop import ClosedLoop
from dvfc.models.robot import Payload


@dataclass(frozen=True)
class Field:
    """A dispersable field: its size (``"1"``, ``"3"``, ``"n"`` joints, ``"2"``, ``"5"``, ``"3m"``
    point coordinates), its domain and whether it is a whole number."""

    size: str
    low: float = -np.inf
    high: float = np.inf
    integer: bool = False


FIELDS = {
    "plant.mount.xyz": Field("3"),
    "plant.mount.rpy": Field("3"),
    "plant.camera.focal_length": Field("1", 1e-9),
    "plant.camera.fx": Field("1", 1e-9),
    "plant.camera.fy": Field("1", 1e-9),
    "plant.camera.principal_point": Field("2"),
    "plant.camera.distortion": Field("5"),
    "plant.target_points": Field("3m"),
    "plant.friction.viscous": Field("n", 0.0),
    "plant.friction.coulomb": Field("n", 0.0),
    "plant.mass_scale": Field("1", 1e-9),
    "plant.payload.mass": Field("1", 0.0),
    "plant.payload.com": Field("3"),
    "plant.payload.inertia": Field("6"),
    "target.motion.radius": Field("1", 0.0),
    "implementation.latency": Field("1", 0.0),
    "implementation.latency_jitter": Field("1", 0.0, integer=True),
    "implementation.frame_drop": Field("1", 0.0, 1.0),
    "implementation.outliers.probability": Field("1", 0.0, 1.0),
    "implementation.outliers.size": Field("1", 0.0),
    "implementation.pixel_noise": Field("1", 0.0),
    "implementation.torque_scale": Field("1", 1e-9),
    "observer.error_xyz": Field("3"),
    "observer.error_rpy": Field("3"),
    "robot.q0": Field("n"),
    "robot.qd0": Field("n"),
}
"""The fields a ``[dispersion]`` may perturb: every one an input of the compiled sampled loop
(or of its start, or of the code between its calls)."""

MASSES = ("plant.mass_scale", "plant.payload.mass", "plant.payload.com", "plant.payload.inertia")
"""The fields that need the loop built with a plant (its masses inputs of the compiled loop)."""
INPUTS = ("target.motion.radius", *MASSES)
"""The fields that are entries of the compiled loop's parameter vector, beside its design."""


def _scenario_paths(data: dict, prefix: str = "") -> list[str]:
    """Every field path of a scenario's dump (for "not dispersable" against "no such field")."""
    out = []
    for key, value in data.items():
        path = f"{prefix}{key}"
        out.append(path)
        if isinstance(value, dict):
            out += _scenario_paths(value, path + ".")
    return out


def check_keys(scenario: Scenario) -> None:
    """Refuse a dispersion on a field that does not exist (with "did you mean"), on one that is
    not an input of the compiled loop, or with choice values outside the field's domain."""
    for key, d in scenario.dispersion.items():
        where = f'dispersion."{key}"'
        if key not in FIELDS:
            known = _scenario_paths(scenario.model_dump(exclude={"dispersion"}))
            if key in known:
                raise ValueError(f"{where}: not dispersable (a constant of the compiled loop); dispersable: "
                                 f"{', '.join(FIELDS)}")  # fmt: skip
            close = difflib.get_close_matches(key, list(FIELDS), n=1, cutoff=0.6)
            hint = f"did you mean {close[0]!r}? " if close else ""
            raise ValueError(f"{where}: no such field; {hint}dispersable: {', '.join(FIELDS)}")
        f = FIELDS[key]
        if d.dist == "choice":
            assert d.values is not None, "a choice has its values (DistributionSection)"
            values = np.asarray([np.ravel(v) for v in d.values], dtype=float)
            if np.any(values < f.low) or np.any(values > f.high):
                raise ValueError(f"{where}.values: outside [{f.low:g}, {f.high:g}]")


def field_size(key: str, n: int, m: int) -> int:
    """Entries of a dispersable field for ``n`` joints and ``m`` feature points."""
    size = FIELDS[key].size
    return {"n": n, "3m": 3 * m}.get(size) or int(size)


def column_names(key: str, size: int) -> list[str]:
    """Dataset columns of a drawn quantity: its key for a scalar, ``key[i]`` per entry of a vector."""
    return [key] if size == 1 else [f"{key}[{i}]" for i in range(size)]


@dataclass(frozen=True)
class Dispersion:
    """The scenario's distributions, checked against the loop's sizes; ``base`` holds the
    scenario's value of each field (flat)."""

    distributions: dict[str, DistributionSection]
    base: dict[str, np.ndarray]

    def __post_init__(self) -> None:
        for key, d in self.distributions.items():
            size = len(self.base[key])
            for name in ("sigma", "low", "high"):
                value = getattr(d, name)
                if isinstance(value, list) and len(value) != size:
                    raise ScenarioError(f'dispersion."{key}".{name}: expected {size} entries, got {len(value)}')
            if d.dist == "choice" and any(np.size(v) != size for v in d.values or ()):
                raise ScenarioError(f'dispersion."{key}".values: each value needs {size} entries')

    @property
    def keys(self) -> list[str]:
        """The drawn quantities, in the order they are drawn (sorted)."""
        return sorted(self.distributions)

    def columns_of(self, key: str) -> list[str]:
        """The dataset columns of one drawn quantity."""
        return column_names(key, len(self.base[key]))

    def columns(self) -> list[str]:
        """Every dataset column of the drawn quantities."""
        return [c for key in self.keys for c in self.columns_of(key)]

    def draw(self, rng: np.random.Generator) -> dict[str, np.ndarray]:
        """One run's values (absolute, within each field's domain)."""
        out = {}
        for key in self.keys:
            d, base, f = self.distributions[key], self.base[key], FIELDS[key]
            size = len(base)
            if d.dist == "normal":
                sigma = np.broadcast_to(np.asarray(d.sigma, float), size)
                z = rng.standard_normal(size)
                while d.clip is not None and np.any(out_of := np.abs(z) > d.clip):  # truncated: redraw beyond clip
                    z[out_of] = rng.standard_normal(int(out_of.sum()))
                value = base + sigma * z
            elif d.dist == "uniform":
                value = base + rng.uniform(np.asarray(d.low, float), np.asarray(d.high, float), size)
            elif d.dist == "lognormal":
                value = base * np.exp(np.broadcast_to(np.asarray(d.sigma, float), size) * rng.standard_normal(size))
            else:
                assert d.values is not None, "a choice has its values (DistributionSection)"
                value = np.ravel(np.asarray(d.values[int(rng.integers(len(d.values)))], float)) * np.ones(size)
            value = np.clip(value, f.low, f.high)
            out[key] = np.round(value) if f.integer else value
        return out

    def box(self) -> list[tuple[float, float]]:
        """The range each column's values can take (normal: ``clip`` sigmas, 3 without; lognormal:
        3 sigmas), within the field's domain: the worst-case search's box."""
        out = []
        for key in self.keys:
            d, base, f = self.distributions[key], self.base[key], FIELDS[key]
            size = len(base)
            if d.dist == "normal":
                half = np.broadcast_to(np.asarray(d.sigma, float), size) * (d.clip or 3.0)
                low, high = base - half, base + half
            elif d.dist == "uniform":
                low, high = base + np.asarray(d.low, float), base + np.asarray(d.high, float)
            elif d.dist == "lognormal":
                factor = np.exp(3 * np.broadcast_to(np.asarray(d.sigma, float), size))
                low, high = base / factor, base * factor
            else:
                values = np.asarray([np.ravel(v) * np.ones(size) for v in d.values or ()], float)
                low, high = values.min(axis=0), values.max(axis=0)
            low, high = np.clip(low, f.low, f.high), np.clip(high, f.low, f.high)
            out += [(float(a), float(b)) for a, b in zip(np.broadcast_to(low, size), np.broadcast_to(high, size),
                                                        strict=True)]  # fmt: skip
        return out

    def split(self, flat: np.ndarray) -> dict[str, np.ndarray]:
        """Column values (:meth:`columns` order) as one array per key."""
        out, i = {}, 0
        for key in self.keys:
            size = len(self.base[key])
            value = np.asarray(flat[i : i + size], float)
            out[key] = np.round(value) if FIELDS[key].integer else value
            i += size
        return out


def with_values(
    settings: Settings, s0: np.ndarray, loop: ClosedLoop, scenario: Scenario, values: dict[str, np.ndarray]
) -> tuple[Settings, np.ndarray]:
    """The settings and initial state of one run: ``values`` (absolute, per key of :data:`FIELDS`)
    applied to the case's ``settings`` (whose ``errors`` are set) and start ``s0``. A drawn ``q0`` or
    ``qd0`` starts the observer as the scenario does (``[start] observer = "image"``: from the first
    image at that ``q0``), a drawn observer error from that error."""
    imp, errors, n = settings.implementation, settings.errors, loop.robot.n
    assert imp is not None and errors is not None, "a campaign's settings (campaign_settings)"
    imp_changes: dict[str, Any] = {}
    err_changes: dict[str, Any] = {}
    input_changes: dict[str, Any] = {}
    payload_changes: dict[str, Any] = {}
    for key, v in values.items():
        section, _, name = key.partition(".")
        if section == "implementation":
            name = {"outliers.probability": "outlier_probability", "outliers.size": "outlier_size"}.get(name, name)
            value = float(v[0])
            if name == "latency":
                value = round(value * imp.control_rate) / imp.control_rate
            imp_changes[name] = int(value) if name == "latency_jitter" else value
        elif key == "plant.mount.xyz":
            err_changes["mount_xyz"] = v
        elif key == "plant.mount.rpy":
            err_changes["mount_rpy"] = v
        elif key == "plant.camera.focal_length":
            err_changes["fx"], err_changes["fy"] = float(v[0]), float(v[0]) * loop.camera.aspect
        elif key in ("plant.camera.fx", "plant.camera.fy"):
            err_changes[name.rpartition(".")[2]] = float(v[0])
        elif key == "plant.camera.principal_point":
            err_changes["principal_point"] = v
        elif key == "plant.camera.distortion":
            err_changes["distortion"] = v
        elif key == "plant.target_points":
            err_changes["point_errors"] = v.reshape(-1, 3)
        elif key.startswith("plant.friction."):
            err_changes[name.rpartition(".")[2]] = v
        elif key == "target.motion.radius":
            input_changes["radius"] = float(v[0])
        elif key == "plant.mass_scale":
            input_changes["mass_scale"] = float(v[0])
        elif key.startswith("plant.payload."):
            entry = name.rpartition(".")[2]
            payload_changes[entry] = float(v[0]) if entry == "mass" else tuple(map(float, v))
    s = s0.copy()
    observer = any(k.startswith("observer.") for k in values)
    if "robot.q0" in values or "robot.qd0" in values or observer:
        o = scenario.observer
        q0 = np.asarray(values.get("robot.q0", s0[:n]), float)
        qd0 = np.asarray(values.get("robot.qd0", s0[n : 2 * n]), float)
        error = SE3.from_xyz_rpy(values.get("observer.error_xyz", o.error_xyz), values.get("observer.error_rpy",
                                                                                            o.error_rpy))  # fmt: skip
        if scenario.start.observer == "image" and not observer:  # gbar(0) from the first image at q0, as s0's
            written = scenario.implementation
            noise, seed = (0.0, 0) if written is None else (written.pixel_noise, written.seed)
            s = image_start(loop, q0, qd0, noise, seed)
        else:
            s = loop.initial_state(q0, qd0, error)
    settings = replace(settings, implementation=replace(imp, **imp_changes), errors=replace(errors, **err_changes))
    if input_changes or payload_changes:
        inputs = settings.inputs or Inputs.of(loop.target, settings.plant)
        if payload_changes:
            input_changes["payload"] = replace(inputs.payload or Payload(0.0), **payload_changes)
        settings = replace(settings, inputs=replace(inputs, **input_changes))
    return settings, s


def base_values(scenario: Scenario, settings: Settings, s0: np.ndarray, n: int) -> dict[str, np.ndarray]:
    """The scenario's value of every dispersable field (flat arrays): the values its runs use
    when nothing is drawn."""
    imp, e = settings.implementation, settings.errors
    assert imp is not None and e is not None, "a campaign's settings (campaign_settings)"
    payload = scenario.plant.payload
    return {
        "plant.mount.xyz": e.mount_xyz, "plant.mount.rpy": e.mount_rpy,
        "plant.camera.focal_length": np.array([e.fx]), "plant.camera.fx": np.array([e.fx]),
        "plant.camera.fy": np.array([e.fy]), "plant.camera.principal_point": np.asarray(e.principal_point, float),
        "plant.camera.distortion": np.asarray(e.distortion, float), "plant.target_points": np.ravel(e.point_errors),
        "plant.friction.viscous": e.viscous, "plant.friction.coulomb": e.coulomb,
        "plant.mass_scale": np.array([scenario.plant.mass_scale]),
        "plant.payload.mass": np.array([0.0 if payload is None else payload.mass]),
        "plant.payload.com": np.zeros(3) if payload is None else np.asarray(payload.com, float),
        "plant.payload.inertia": np.zeros(6) if payload is None else np.asarray(payload.inertia, float),
        "target.motion.radius": np.array([scenario.target.motion.radius]),
        "implementation.latency": np.array([imp.latency]),
        "implementation.latency_jitter": np.array([float(imp.latency_jitter)]),
        "implementation.frame_drop": np.array([imp.frame_drop]),
        "implementation.outliers.probability": np.array([imp.outlier_probability]),
        "implementation.outliers.size": np.array([imp.outlier_size]),
        "implementation.pixel_noise": np.array([imp.pixel_noise]),
        "implementation.torque_scale": np.array([imp.torque_scale]),
        "observer.error_xyz": np.asarray(scenario.observer.error_xyz, float),
        "observer.error_rpy": np.asarray(scenario.observer.error_rpy, float),
        "robot.q0": s0[:n].copy(), "robot.qd0": s0[n : 2 * n].copy(),
    }  # fmt: skip
