"""Benchmark: certificate throughput on a grid of 1e5 isotropic gain points.

In one run: the vectorised exact route (:func:`dvfc.analysis.grid.certify_batch`) in memory,
the same grid end to end (:func:`dvfc.analysis.grid.run_sweep`: batches stored as Parquet,
atomically, with the resumable state) and its bytes a point on disk, the per-point
Clarabel SDP on a sample of the same points, and raw batched ``numpy.linalg.eigvalsh`` of
as many 12x12 matrices (the ceiling); then the time of one anisotropic sound certificate
with its worst-rotation search; then the operating envelope of one design (docs/math.md,
facts 7-9, the rate of docs/math.md, fact 10) with and without the searches for the largest target
speed and torque, against one exact gamma of the same design, and with the UR5's matrix inertia
bound against the scalar one (``D_M = lambda_max(B) I``, the rate before fact 10). Prints
points/s and ratios (goal for the grid: end to end >= 0.8 of in memory, <= 30 bytes a point;
for the envelope with the matrix bound: within 2x of the scalar route).
"""

from __future__ import annotations

import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from timing import median_of

from dvfc.analysis.certify import GainPoint, certify, exact_gamma, sdp_gamma
from dvfc.analysis.envelope import DisturbanceBounds, design_of, envelope, grid_envelope
from dvfc.analysis.grid import POINTS, GridSpec, certify_batch, run_sweep
from dvfc.models.camera import Camera
from dvfc.models.inertia import MassBounds, mass_matrix_bounds
from dvfc.models.lie import SE3
from dvfc.models.loop import Weights
from dvfc.models.robot import BUILTIN_CAMERA_FRAME, builtin_urdf, chain_joints

SQUARE = np.array([[0.05, 0.05, 0.0], [-0.05, 0.05, 0.0], [-0.05, -0.05, 0.0], [0.05, -0.05, 0.0]])


def ur5_mass_bounds() -> MassBounds:
    """The UR5's inertia bounds from its URDF (:mod:`dvfc.models.inertia`)."""
    urdf = builtin_urdf("ur5")
    return mass_matrix_bounds(urdf, chain_joints(urdf, BUILTIN_CAMERA_FRAME["ur5"]))


def envelope_timings(design: GainPoint, reference: SE3, mass: MassBounds) -> None:
    """One design's envelope (the model built: mass bounds and V(0) given) against one exact gamma,
    and with the matrix inertia bound of fact 10 against the scalar ``lambda_max(B) I`` (for every
    ``v``, ``D_M(v) = lambda_max(B) I`` then: the rate of the scalar route, by the same code)."""
    camera = Camera(800.0, SQUARE, 1280.0, 1024.0)
    scalar = replace(mass, upper=np.diag(np.full(len(mass.mu), mass.m_hi)))
    bounds = DisturbanceBounds(0.0785, 0.0, 0.05)
    start = {"V0": 0.002}
    gamma = median_of(lambda: exact_gamma(design, reference, np.eye(3)))
    plain = median_of(lambda: envelope(design_of(design, reference, mass), camera, bounds, start, search=False))
    old = median_of(lambda: envelope(design_of(design, reference, scalar), camera, bounds, start, search=False))
    full = median_of(lambda: envelope(design_of(design, reference, mass), camera, bounds, start))
    print("operating envelope of one design (median of 20)")
    print(f"  one exact gamma (baseline)                {gamma * 1e3:12,.2f} ms")
    print(f"  envelope: rate, bounds, boxes, start      {plain * 1e3:12,.2f} ms  ({plain / gamma:,.1f}x the baseline)")
    print(f"  same, scalar inertia bound lambda_max(B)  {old * 1e3:12,.2f} ms  (matrix / scalar {plain / old:,.2f})")
    print(f"  envelope with largest speed and torque    {full * 1e3:12,.2f} ms  ({full / gamma:,.1f}x the baseline)")


def main() -> None:
    reference = SE3.from_xyz_rpy([0.0, 0.0, 0.35], [0.0, 0.0, 0.0])
    axes = (("k_c", np.geomspace(0.5, 10, 100)), ("k_e_p", np.linspace(1, 20, 50)), ("k_e_r", np.linspace(1, 20, 20)))
    design = GainPoint(np.full(6, 20.0), np.full(6, 3.0), np.full(6, 10.0), Weights(4, 1, 4, 1))
    spec = GridSpec.around(design, reference, axes)
    size = spec.size
    certify_batch(spec, 0, 100)
    start = time.perf_counter()
    for lo in range(0, size, 20000):
        certify_batch(spec, lo, min(lo + 20000, size))
    exact = size / (time.perf_counter() - start)

    with tempfile.TemporaryDirectory() as out:
        start = time.perf_counter()
        run_sweep(spec, Path(out))
        stored = size / (time.perf_counter() - start)
        disk = sum(f.stat().st_size for f in (Path(out) / POINTS).iterdir())

    sample = np.linspace(0, size - 1, 20).astype(int)
    start = time.perf_counter()
    for i in sample:
        d = spec.designs(i, i + 1)
        sdp_gamma(GainPoint(d["k_xi"][0], d["k_c"][0], d["k_e"][0], Weights(*d["w"][0])), reference, np.eye(3))
    sdp = len(sample) / (time.perf_counter() - start)

    rng = np.random.default_rng(0)
    m = rng.normal(size=(size, 12, 12))
    m = m + m.transpose(0, 2, 1)
    start = time.perf_counter()
    np.linalg.eigvalsh(m)
    ceiling = size / (time.perf_counter() - start)

    point = GainPoint(np.full(6, 20.0), np.full(6, 3.0), np.array([10, 5, 20, 8, 3, 12.0]), Weights(4, 1, 4, 1))
    start = time.perf_counter()
    cert = certify(point, reference, with_sdp=False)
    anisotropic = time.perf_counter() - start

    print(f"grid of {size:,} isotropic points (exact route, batches of 20,000)")
    print(f"  exact closed form + a posteriori check   {exact:12,.0f} points/s")
    print(f"  same, end to end to Parquet (run_sweep)  {stored:12,.0f} points/s")
    print(f"  end to end / in memory                    {stored / exact:12,.2f}")
    print(f"  on disk                                   {disk / size:12,.1f} bytes a point")
    print(f"  per-point SDP (Clarabel), 20 samples      {sdp:12,.1f} points/s")
    print(f"  batched eigvalsh of 12x12 (ceiling)       {ceiling:12,.0f} points/s")
    print(f"  exact / SDP                               {exact / sdp:12,.0f}x")
    print(f"  ceiling / exact                           {ceiling / exact:12,.2f}x")
    print(f"  anisotropic sound certificate + search    {anisotropic * 1e3:12,.1f} ms  (gap {cert.gap:.2%})")
    mass = ur5_mass_bounds()
    envelope_timings(design, reference, mass)
    envelope_grid(design, reference, axes, exact, mass)


def envelope_grid(design: GainPoint, reference: SE3, axes, plain: float, mass: MassBounds) -> None:
    """The same grid with the envelope columns (rate, max_target_speed) against the plain rate."""
    camera = Camera(800.0, SQUARE, 1280.0, 1024.0)
    context = grid_envelope(design_of(design, reference, mass), camera,
                            DisturbanceBounds(0.0785, 0.0, 0.05), None)  # fmt: skip
    spec = GridSpec.around(design, reference, axes, None, context)
    certify_batch(spec, 0, 100)
    start = time.perf_counter()
    for lo in range(0, spec.size, 20000):
        certify_batch(spec, lo, min(lo + 20000, spec.size))
    rate = spec.size / (time.perf_counter() - start)
    print(f"grid with the envelope columns          {rate:12,.0f} points/s  ({rate / plain:.2f} of the plain grid)")


if __name__ == "__main__":
    main()
