"""Mutation harness: break the code on purpose and check that the tests notice.

Each :class:`Mutation` is a list of exact source-text substitutions and the tests expected to
catch it. For each one the repository's tracked files are copied to a temporary directory,
the substitutions are applied there (each pattern must occur exactly the stated number of
times: a pattern that no longer matches the code is a harness error, never a silent pass),
and pytest runs the named tests on the copy. The mutation is caught when pytest reports a
failing test (exit status 1); it survives when they pass (exit 0); anything else (a
collection error, no tests collected) is a harness error. The unmutated copy must pass the
same tests first.

Run ``make mutate`` (or ``.venv/bin/python tests/mutation/harness.py [--only NAME] [--write]``);
``--write`` rewrites the result table in ``MUTATIONS.md`` beside this file. Exit status 0 only when every
mutation is caught.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent.parent
TABLE = Path(__file__).resolve().parent / "MUTATIONS.md"
LAYERS = ("models", "analysis", "reports")
"""The top-level folders installed as ``dvfc.models``, ``dvfc.analysis``, ``dvfc.reports``."""


@dataclass(frozen=True)
class Mutation:
    name: str
    what: str
    path: str
    substitutions: tuple[tuple[str, str], ...]
    tests: tuple[str, ...]
    count: int = 1
    """How many times each pattern must occur in ``path``."""


MUTATIONS = (
    # --- fact 14 for the plant as declared ---------------------------------------------
    Mutation(
        "fact-14-for-the-model-not-the-plant",
        "fact 14 linearises the controller's model while the scenario declares another plant",
        "analysis/multirate.py",
        (("    plant = DeclaredPlant.of(settings)\n    words = ", "    plant = DeclaredPlant()\n    words = "),),
        ("tests/test_multirate_statements.py::test_fact_14_is_stated_for_the_plant_as_declared",),
    ),
    Mutation(
        "true-camera-ignored-at-the-equilibrium",
        "the plant's equilibrium and linearisation read the nominal camera's image, not the true camera's",
        "analysis/multirate.py",
        (("    camera, differs = plant.camera_errors(loop.camera), plant.differs(loop.camera)\n",
          "    camera, differs = None, plant.differs(loop.camera)\n"),),
        ("tests/test_multirate_statements.py::test_the_sampled_loop_settles_at_the_equilibrium_of_the_plant_as_declared",),
    ),
    Mutation(
        "plant-margin-not-linearised",
        "a payload, mount, focal-length or friction margin judged by its runs alone (no plant linearised at its value)",
        "analysis/margins.py",
        (("        if self.system is None or name not in LINEAR + PLANT:\n",
          "        if self.system is None or name not in LINEAR:\n"),),
        ("tests/test_margins.py::test_a_plant_parameter_is_checked_on_the_plant_linearised_at_its_value",),
    ),
    Mutation(
        "self-motion-equilibria-unchecked",
        "fact 14 across the self-motion certified without checking that its poses are equilibria",
        "analysis/multirate.py",
        (("        manifold = self.dimension == 0 or (self.equilibria is not None and self.equilibria.holds)\n",
          "        manifold = True\n"),),
        ("tests/test_multirate.py::test_an_isolated_fixed_point_whose_map_fixes_the_tangent_is_not_the_self_motion",),
    ),
    Mutation(
        "self-motion-check-ignores-displacement",
        "the self-motion's poses taken for equilibria when Newton converges, even back to the isolated one",
        "analysis/multirate.py",
        (("        return self.residual < EQUILIBRIUM_TOLERANCE and self.moved >= 0.5\n",
          "        return self.residual < EQUILIBRIUM_TOLERANCE\n"),),
        ("tests/test_multirate.py::test_an_isolated_fixed_point_whose_map_fixes_the_tangent_is_not_the_self_motion",),
    ),
    Mutation(
        "self-motion-tangent-joints-only",
        "the self-motion's tangent taken in the joints only when the plant's equilibria move z_I along it",
        "analysis/multirate.py",
        (("        if lin.tangent is None:\n            return np.vstack([lin.self_motion,",
          "        if True:\n            return np.vstack([lin.self_motion,"),),
        ("tests/test_multirate.py::test_a_payload_on_the_seven_joint_arm_moves_its_equilibria_with_the_integral_state",),
    ),
    Mutation(
        "campaign-locally-unstable-draw-holds",
        "a campaign draw whose plant fact 14 does not certify counted as holding when its run held",
        "analysis/campaign.py",
        (("    if verdict is not None and not verdict.certified:  # a failure whatever its run shows\n",
          "    if False:\n"),),
        ("tests/test_campaign_statistics.py::test_a_draw_whose_plant_is_locally_unstable_fails_whatever_its_run",),
    ),
    Mutation(
        "campaign-local-rho-of-the-model",
        "a campaign draw's local rho computed for the controller's model, not the plant as drawn",
        "analysis/campaign.py",
        (("    return DeclaredPlant.of(settings).verdict(", "    return DeclaredPlant().verdict("),),
        ("tests/test_campaign_statistics.py::test_a_draw_whose_plant_is_locally_unstable_fails_whatever_its_run",),
    ),
    Mutation(
        "plant-margin-not-clipped",
        "a payload, mount, focal-length or friction margin reported beyond fact 14's linear margin of the plant",
        "analysis/margins.py",
        (("    plant_margin = None if linear is None or name not in PLANT else linear.margin(name, start, end)\n",
          "    plant_margin = None\n"),),
        ("tests/test_margins.py::test_a_plant_parameters_margin_is_never_beyond_its_linear_margin",),
    ),
    # --- the seven of the audit --------------------------------------------------------
    Mutation(
        "grid-kmin-max",
        "the sound K_e (grid, certifier, envelope) takes the blockwise max instead of the min (fact 5)",
        "analysis/certify.py",
        (("k_e[..., :3].min(axis=-1), k_e[..., 3:].min(axis=-1)", "k_e[..., :3].max(axis=-1), k_e[..., 3:].max(axis=-1)"),),  # noqa: E501
        ("tests/test_reference.py::test_grid_rows_are_sound_complete_and_minimal",),
    ),
    Mutation(
        "xi-block-dropped",
        "the xi block term dropped from the closed form (k_xi >= 1/2 + 1/(2 gamma^2))",
        "analysis/certify.py",
        (("    s = np.minimum(s, xi_limit)\n", ""),),
        ("tests/test_reference.py::test_certificate_is_sound_complete_and_minimal",),
    ),
    Mutation(
        "xi-disturbance-weight-dropped",
        "the xi block's limit without the torque weight D_tau (fact 17)",
        "analysis/certify.py",
        (("    return ((k_xi - 0.5 * np.square(plant.xi)) / np.square(plant.tau_d)).min(axis=1)\n",
          "    return (k_xi - 0.5 * np.square(plant.xi)).min(axis=1)\n"),),
        ("tests/test_reference.py::test_weighted_certificate_is_sound_complete_and_minimal",),
    ),
    Mutation(
        "target-velocity-weight-dropped",
        "W on e_e without the target-velocity weights D_v (W_e in place of W_e D_v, fact 17)",
        "analysis/certify.py",
        (("    return w_e * plant.disturbance(task)[len(plant.tau_d) :]\n", "    return w_e\n"),),
        ("tests/test_reference.py::test_weighted_certificate_is_sound_complete_and_minimal",),
    ),
    Mutation(
        "output-weight-dropped-from-quadrature",
        "the run's integral of |z|^2 taken unweighted (|x|^2 for |S x|^2, fact 17)",
        "models/loop.py",
        (("            self.z.T @ self.z,\n", "            self.x.T @ self.x,\n"),),
        ("tests/test_generalized_plant.py::test_weighted_theorem_2_holds_from_rest_and_bites",),
    ),
    Mutation(
        "plan-ignores-hold",
        "the planned reference starts at t = 0, before the first image has arrived (fact 16b)",
        "models/loop.py",
        (("            return cs.fmin(cs.fmax((t - self.hold) / self.duration, 0), 1)\n",
          "            return cs.fmin(cs.fmax(t / self.duration, 0), 1)\n"),),
        ("tests/test_start.py::test_the_arm_is_held_until_the_first_image_arrives",),
    ),
    Mutation(
        "linearisation-unweighted",
        "the lower bound's linearisation left unweighted (w -> x for d -> z, fact 17)",
        "analysis/linearize.py",
        (("    b, c, d = b * d_w, s[:, None] * c, s[:, None] * d * d_w\n", "    b, c, d = b, c, d\n"),),
        ("tests/test_generalized_plant.py::test_weighted_linearisation_is_below_the_weighted_gamma",),
    ),
    Mutation(
        "worst-rotation-search-off",
        "the certifier's worst-rotation search disabled (identity only, no refinement)",
        "analysis/certify.py",
        (("    best = int(np.argmax(values))\n", "    best = 0\n"), ("    for _ in range(rounds):\n", "    for _ in ():\n")),  # noqa: E501
        ("tests/test_reference.py::test_certificate_is_sound_complete_and_minimal",),
    ),
    Mutation(
        "sweep-keeps-stale-parts",
        "a sweep keeps the batch files beyond its recorded point (the audit's resume without truncation, "
        "as it reads for one Parquet file per batch)",
        "analysis/batches.py",
        (("                part.unlink()\n", "                pass\n"),),
        ("tests/test_grid.py::test_new_sweep_replaces_an_older_larger_one",),
    ),
    Mutation(
        "inflation-1e-3",
        "the certified gamma inflated by 1e-3 instead of 1e-6 (not minimal)",
        "analysis/certify.py",
        (("INFLATION = 1e-6\n", "INFLATION = 1e-3\n"),),
        ("tests/test_reference.py::test_certificate_is_sound_complete_and_minimal",),
    ),
    Mutation(
        "coriolis-transposed",
        "Coriolis matrix C = (Mdot - B + B^T)/2 (Mdot - 2C is still skew)",
        "models/robot.py",
        (("        return (mdot + b - b.T) / 2\n", "        return (mdot - b + b.T) / 2\n"),),
        ("tests/test_robot.py",),
    ),
    Mutation(
        "schur-a_ce-untransposed",
        "the Schur complement uses A_ce instead of A_ce^T (equal at R_ec = I)",
        "analysis/certify.py",
        (('np.einsum("bji,bjk->bik", a_ce[ok]', 'np.einsum("bij,bjk->bik", a_ce[ok]'),),
        ("tests/test_reference.py::test_certificate_is_sound_complete_and_minimal",),
    ),
    # --- the law, the observer, the camera ------------------------------------------------
    Mutation(
        "law-feedback-sign",
        "the law (35) feeds back -J_b^T Ad^T W_c e_c (sign of the passivity term)",
        "models/loop.py",
        (("feedforward + r.body_jacobian.T @ ad_d.T", "feedforward - r.body_jacobian.T @ ad_d.T"),),
        ("tests/test_loop.py",),
    ),
    Mutation(
        "observer-input-sign",
        "the observer (12) integrates -u_e instead of u_e",
        "models/loop.py",
        (("@ self.camera_velocity + self._camera_inputs[1]", "@ self.camera_velocity - self._camera_inputs[1]"),),
        ("tests/test_loop.py",),
    ),
    Mutation(
        "camera-jacobian-depth-term",
        "the image Jacobian (19) with +l x / z^2 (sign of the depth derivative)",
        "models/camera.py",
        (("cs.horzcat(lam / z, 0, -lam * x / z**2)", "cs.horzcat(lam / z, 0, lam * x / z**2)"),),
        ("tests/test_camera.py",),
    ),
    # --- certificates ------------------------------------------------------------------
    Mutation(
        "certifier-weight-scaling",
        "the closed form scales the Schur complement by W_e^-1/2 instead of W_e^-1",
        "analysis/certify.py",
        (("        d = 1.0 / w_e[ok]  # D^-1/2 = W_e^-1\n", "        d = 1.0 / np.sqrt(w_e[ok])\n"),),
        ("tests/test_reference.py::test_certificate_is_sound_complete_and_minimal",),
    ),
    Mutation(
        "tight-gamma-half",
        "the fact-4 gamma at alpha computed with alpha^2/4 instead of alpha^2/2",
        "analysis/certify.py",
        (("math.sqrt(alpha**2 / 2 * np.linalg.eigvalsh", "math.sqrt(alpha**2 / 4 * np.linalg.eigvalsh"),),
        ("tests/test_reference.py::test_tight_certificate_is_sound_complete_and_minimal",),
    ),
    Mutation(
        "tight-anisotropic-at-identity",
        "the fact-4 certificate for anisotropic K_e evaluated at R = I with the true K_e (not sound for every R)",
        "analysis/certify.py",
        (("    sound = point.with_k_e(sound_k_e(point.k_e))\n    nkn_, g, s2 = _tight_blocks(", "    sound = point\n    nkn_, g, s2 = _tight_blocks("),),  # noqa: E501
        ("tests/test_reference.py::test_tight_certificate_is_sound_complete_and_minimal",),
    ),
    Mutation(
        "planar-certifier-weight",
        "the planar certificate (P11) weighs e_e by w_pc instead of w_pe",
        "analysis/certify.py",
        (("else np.full(task, float(weights.w_pe))\n", "else np.full(task, float(weights.w_pc))\n"),),
        ("tests/test_reference.py::test_planar_certificates_are_sound_complete_and_minimal",),
    ),
    Mutation(
        "grid-planar-weight",
        "the planar grid weighs e_e by w_pc instead of w_pe",
        "analysis/grid.py",
        (('np.repeat(d["w"][:, 2:3], TASK, axis=1)', 'np.repeat(d["w"][:, 0:1], TASK, axis=1)'),),
        ("tests/test_reference.py::test_grid_rows_are_sound_complete_and_minimal",),
    ),
    # --- lower bounds, Theorem 2 on trajectories, resume ---------------------------------
    Mutation(
        "lower-bound-doubled-energy",
        "the from-rest search reports sqrt(2) times the gain it measured (its lower bound too high)",
        "analysis/linearize.py",
        (("            return ratio, traj, True\n", "            return math.sqrt(2) * ratio, traj, True\n"),),
        ("tests/test_theorem2.py",),
    ),
    Mutation(
        "synthesis-objective",
        "the smallest-gain synthesis leaves K_e out of the norm it minimises",
        "analysis/synthesize.py",
        (("cp.Minimize(cp.norm(cp.hstack([k_xi, k_ce])))", "cp.Minimize(cp.norm(cp.hstack([k_xi, k_c])))"),),
        ("tests/test_synthesize.py",),
    ),
    Mutation(
        "certified-gamma-under-reported",
        "the certifier reports 0.9 gamma and its a posteriori check is fooled (P shifted by W / (2 gamma^2))",
        "analysis/certify.py",
        (("    gamma = gamma_exact * (1 + INFLATION)\n", "    gamma = 0.9 * gamma_exact * (1 + INFLATION)\n    a = a + w / (2 * gamma**2)\n"),),  # noqa: E501
        ("tests/test_theorem2.py",),
    ),
    Mutation(
        "resume-state-before-data",
        "the sweep state is saved before the batch's file is written",
        "analysis/batches.py",
        (
            (
                "                written = table(result)\n",
                "                state = {**(state if absorb is None else absorb(state, result)), \"done\": stop}\n"
                "                self._save(state)\n                written = table(result)\n",
            ),
            (
                "                state = {**(state if absorb is None else absorb(state, result)), \"done\": stop}\n"
                "                self._save(state)\n                if progress",
                "                if progress",
            ),
        ),
        ("tests/test_grid.py::test_crash_between_data_write_and_state_save_resumes_exactly",),
    ),
    # --- the operating envelope (facts 7-8) and the inertia bounds (docs/math.md, fact 10) ------------
    Mutation(
        "self-consistent-level-max",
        "the self-consistent level taken with the larger of the two rotational weights",
        "analysis/envelope.py",
        (("np.minimum(weights[..., 1], weights[..., 3])", "np.maximum(weights[..., 1], weights[..., 3])"),),
        ("tests/test_envelope.py::test_self_consistent_level_keeps_both_rotations_within_theta_bar",),
    ),
    Mutation(
        "recheck-half-d",
        "the a posteriori rate check made against half of D",
        "analysis/envelope.py",
        (("- kappa[:, None, None] * (d[:, :, None] * eye))[:, 0]", "- kappa[:, None, None] * (d[:, :, None] * eye) / 2)[:, 0]"),),  # noqa: E501
        ("tests/test_envelope.py::test_recheck_refuses_a_rate_above_the_certified_one",),
    ),
    Mutation(
        "recheck-joint-block-free",
        "the a posteriori rate check made without the kinetic block D_M / 2 of D",
        "analysis/envelope.py",
        (("    return np.concatenate([d_m / 2, design.d_diagonal", "    return np.concatenate([0 * d_m, design.d_diagonal"),),  # noqa: E501
        ("tests/test_envelope.py::test_recheck_refuses_a_rate_above_the_certified_one",),
    ),
    Mutation(
        "depth-radius-added",
        "the smallest certified depth computed with the radius added instead of subtracted",
        "analysis/envelope.py",
        (("np.min(centres[..., 2] - radius)", "np.min(centres[..., 2] + radius)"),),
        ("tests/test_envelope.py::test_a_design_whose_regions_reach_zero_depth_is_not_visible",),
    ),
    Mutation(
        "radius-frobenius",
        "fact 16.0's joint radius from the Frobenius norm ||R - I||_F = 2 sqrt(phi) instead of the spectral one",
        "analysis/envelope.py",
        (("(1.0 / w_rc + 1.0 / w_re)", "(2.0 / w_rc + 2.0 / w_re)"),),
        ("tests/test_envelope.py::test_joint_radius_bounds_every_feature_offset_and_is_attained",),
    ),
    Mutation(
        "radius-without-estimation",
        "fact 16.0's joint radius without the estimation error's position term 1/w_pe (too small: unsound)",
        "analysis/envelope.py",
        (("    spread = 1.0 / w_pc + 1.0 / w_pe\n", "    spread = 1.0 / w_pc\n"),),
        ("tests/test_envelope.py::test_joint_radius_bounds_every_feature_offset_and_is_attained",),
    ),
    Mutation(
        "cone-3d-distance",
        "fact 16.0's cone interval with the 3-D distance |c_i| instead of the 2-D one per image axis",
        "analysis/envelope.py",
        (("    distance = np.hypot(lateral, depth)\n", "    distance = np.linalg.norm(centres, axis=-1)\n"),),
        ("tests/test_envelope.py::test_cone_interval_contains_the_ball_and_touches_its_ends",),
    ),
    Mutation(
        "feedforward-inverse-adjoint",
        "fact 16b's feedforward -Ad_(g_d^-1) V_d instead of -Ad_(g_d) V_d",
        "models/loop.py",
        (("command = command - self.desired.adjoint() @ self.desired_velocity",
          "command = command - self.desired.inverse().adjoint() @ self.desired_velocity"),),
        ("tests/test_start.py::test_storage_rate_is_minus_nu_k_nu_plus_x_g_w_along_the_start",),
    ),
    Mutation(
        "feedforward-sign",
        "fact 16b's feedforward added with the wrong sign, +Ad_(g_d) V_d",
        "models/loop.py",
        (("command = command - self.desired.adjoint() @ self.desired_velocity",
          "command = command + self.desired.adjoint() @ self.desired_velocity"),),
        ("tests/test_start.py::test_storage_rate_is_minus_nu_k_nu_plus_x_g_w_along_the_start",),
    ),
    Mutation(
        "qdd-d-without-time",
        "qdd_d without the explicit time derivative (through g_d(t) and the target): rate of t taken as 0",
        "models/loop.py",
        (("rates = cs.vertcat(self.qd, 1, estimate_rate)", "rates = cs.vertcat(self.qd, 0, estimate_rate)"),),
        ("tests/test_start.py::test_storage_rate_is_minus_nu_k_nu_plus_x_g_w_along_the_start",),
    ),
    Mutation(
        "ramp-dissipation-fixed-k",
        "fact 16a's dissipation nu^T K nu with the fixed K_c instead of sigma(t) K_c",
        "models/loop.py",
        (("cs.vertcat(gain_column(k.k_xi), self.ramp_level * gain_column(k.k_c), gain_column(k.k_e))",
          "cs.vertcat(gain_column(k.k_xi), gain_column(k.k_c), gain_column(k.k_e))"),),
        ("tests/test_start.py::test_storage_rate_is_minus_nu_k_nu_plus_x_g_w_along_the_start",),
    ),
    Mutation(
        "perron-vector-ones",
        "D_M(v) built with v = 1 instead of the Perron vector of diag(k_xi - s)^-1 B",
        "analysis/envelope.py",
        (
            (
                "mass.upper_diagonal(scale * np.maximum(top, PERRON_FLOOR * top.max(axis=1, keepdims=True)))",
                "mass.upper_diagonal(np.ones_like(scale))",
            ),
        ),
        (
            "tests/test_inertia.py::test_perron_rate_is_never_below_the_scalar_rate",
            "tests/test_envelope.py::test_certify_reports_the_inertia_matrices_of_the_rate",
        ),
    ),
    Mutation(
        "carrier-full-length",
        "B uses the full length |c_L| where the exact carrier entry |a_c x c_L| belongs",
        "models/inertia.py",
        (("beta = [float(np.linalg.norm(np.cross(axes[where.carrier], p)))]", "beta = [float(np.linalg.norm(p))]"),),
        ("tests/test_inertia.py::test_entries_are_bounded_and_the_carrier_entries_attained",),
    ),
    Mutation(
        "carrier-alpha-spectral",
        "B's carrier rotational term lambda_max(I_L) instead of the exact a_c^T S a_c",
        "models/inertia.py",
        (("        alpha[0, 0] = a @ spin @ a  # exact\n", "        alpha[0, 0] = item.principal[-1]\n"),),
        ("tests/test_inertia.py::test_entries_are_bounded_and_the_carrier_entries_attained",),
    ),
    Mutation(
        "lower-bound-p-dropped",
        "the lower bound's P dropped from lambda_max(mu^-1/2 Delta^T P Delta mu^-1/2)",
        "models/inertia.py",
        (("(delta.T @ (p[:, None] * delta))", "(delta.T @ delta)"),),
        ("tests/test_inertia.py::test_m_minus_lower_bound_is_positive_semidefinite",),
    ),
    Mutation(
        "fixed-joint-rotation-dropped",
        "offsets composed through fixed joints without their rotations",
        "models/inertia.py",
        (("rotation, translation = r @ rotation, r @ translation + _vector", "rotation, translation = r @ rotation, translation + _vector"),),  # noqa: E501
        ("tests/test_inertia.py::test_entries_are_bounded_and_the_carrier_entries_attained",),
    ),
    Mutation(
        "synthesis-xi-block-diagonal",
        "the target-speed SDP's joint block with diag(B) in place of B (the inertia coupling dropped)",
        "analysis/synthesize.py",
        (("    q_xi = cp.diag(k_xi) - s * np.eye(n) - kappa * (mass.upper / 2)\n",
          "    q_xi = cp.diag(k_xi) - s * np.eye(n) - kappa * (np.diag(np.diag(mass.upper)) / 2)\n"),),
        ("tests/test_envelope.py::test_target_speed_sdp_rate_is_the_envelope_rate",),
    ),
    # --- the loop as implemented ---------------------------------------------------------
    Mutation(
        "rk4-weights",
        "the sampled loop's RK4 weighs its stages (1, 3, 1, 1)/6 (second order)",
        "analysis/sampled.py",
        (("s = s + step / 6 * (k1 + 2 * k2 + 2 * k3 + k4)", "s = s + step / 6 * (k1 + 3 * k2 + k3 + k4)"),),
        ("tests/test_sampled.py::test_rk4_between_samples_is_fourth_order",),
    ),
    Mutation(
        "images-arrive-late",
        "each image's e_e is used one control period after its latency",
        "analysis/sampled.py",
        (
            ("measure_through(k, arrivals)) is not", "measure_through(k - 1, arrivals)) is not"),
            ("min(int(arrivals[measured]), steps)", "min(int(arrivals[measured]) + 1, steps)"),
        ),
        ("tests/test_sampled.py::test_sampled_run_equals_a_sample_by_sample_loop",),
    ),
    Mutation(
        "last-images-unchecked",
        "the images captured in the last latency (arriving after T) are not checked for lost features",
        "analysis/sampled.py",
        (("if stops else steps, captures)", "if stops else steps - imp.latency_steps, captures)"),),
        ("tests/test_sampled.py::test_a_feature_lost_in_an_image_arriving_after_the_horizon_still_ends_the_run",),
    ),
    # --- the local certificate of the loop as implemented (fact 14) ------------------------
    Mutation(
        "multirate-hold-euler",
        "the zero-order-hold flow over a control period replaced by one explicit Euler step",
        "analysis/multirate.py",
        (("flow = scipy.linalg.expm(generator * h)[:nz]", "flow = (np.eye(len(generator)) + generator * h)[:nz]"),),
        ("tests/test_multirate.py::test_monodromy_equals_a_sample_by_sample_simulation_of_the_linearised_loop",),
    ),
    Mutation(
        "multirate-latency-one-short",
        "the delay line of the monodromy one control period shorter than the latency",
        "analysis/multirate.py",
        (("steps, lag = fraction.numerator, round(periods)\n", "steps, lag = fraction.numerator, round(periods) - 1\n"),),  # noqa: E501
        ("tests/test_multirate.py::test_monodromy_equals_a_sample_by_sample_simulation_of_the_linearised_loop",),
    ),
    Mutation(
        "multirate-lyapunov-wrong-matrix",
        "the Lyapunov decrease checked as P - Pi P Pi^T instead of P - Pi^T P Pi",
        "analysis/multirate.py",
        (("decrease = p - pi.T @ p @ pi\n", "decrease = p - pi @ p @ pi.T\n"),),
        ("tests/test_multirate.py::test_lyapunov_check_certifies_only_a_decreasing_positive_definite_form",),
    ),
    Mutation(
        "multirate-p-definiteness-unchecked",
        "the Lyapunov check certifies without P > 0 (an unstable monodromy passes)",
        "analysis/multirate.py",
        (("bool(p_min > 0 and margin >= LYAPUNOV_MARGIN)", "bool(margin >= LYAPUNOV_MARGIN)"),),
        ("tests/test_multirate.py::test_lyapunov_check_certifies_only_a_decreasing_positive_definite_form",),
    ),
    Mutation(
        "multirate-self-motion-kept",
        "on a redundant arm rho taken of the whole monodromy, the self-motion's eigenvalue 1 with it",
        "analysis/multirate.py",
        (("    m = self_motion.shape[1]\n    if m == 0:\n", "    m = self_motion.shape[1]\n    if True:\n"),),
        ("tests/test_multirate.py::test_on_a_seven_joint_arm_pi_fixes_the_self_motion_and_rho_is_that_across_it",),
    ),
    Mutation(
        "multirate-self-motion-in-qd",
        "the self-motion's tangent placed in the joint velocities instead of the joint angles",
        "analysis/multirate.py",
        (("    tangent[: self_motion.shape[0]] = self_motion\n",
          "    tangent[self_motion.shape[0] : 2 * self_motion.shape[0]] = self_motion\n"),),
        ("tests/test_multirate.py::test_on_a_seven_joint_arm_pi_fixes_the_self_motion_and_rho_is_that_across_it",),
    ),
    Mutation(
        "multirate-tangent-residual-unchecked",
        "a tangent the monodromy does not fix certified (the residual ||Pi T - T|| not compared)",
        "analysis/multirate.py",
        (("return check.certified and self.residual < check.tolerance", "return check.certified"),),
        ("tests/test_multirate.py::test_a_tangent_the_monodromy_does_not_fix_is_not_certified",),
    ),
    Mutation(
        "margins-torque-unchecked",
        "the margins' criterion ignores the torque limits when saturate is off",
        "analysis/margins.py",
        (("    if ratio > 1 and not settings.sampled.saturate:\n",
          "    if ratio > 1e9 and not settings.sampled.saturate:\n"),),
        ("tests/test_margins.py",),
    ),
    Mutation(
        "windows-hold-by-half",
        "the hold limit taken at h lambda_max <= 1 - margin instead of 2 - margin",
        "analysis/windows.py",
        (("h)[-1] <= 2 - margin  #", "h)[-1] <= 1 - margin  #"),),
        ("tests/test_windows.py",),
    ),
    Mutation(
        "implemented-storage-without-delta",
        "fact 11's identity checked without the hold channel int xi^T delta",
        "analysis/verify.py",
        ((' - i["supply_x_G_w"] - i["unmodelled_supply"]', ' - i["supply_x_G_w"]'),),
        ("tests/test_windows.py",),
    ),
    Mutation(
        "synthesize-no-recheck",
        "a synthesized design is written without the fact-14 re-check",
        "analysis/synthesize.py",
        (('    return within and run.get("sampled") is None', '    return within'),),
        ("tests/test_synthesize.py::test_no_design_of_the_family_passing_fact_14_with_margin_is_refused_in_one_line",),
    ),
    Mutation(
        "distortion-tangential-swapped",
        "the true camera's tangential distortion terms p1 and p2 swapped",
        "models/errors.py",
        (("    tx = 2 * k[2] * x * y + k[3] * (r2 + 2 * x**2)\n", "    tx = 2 * k[3] * x * y + k[2] * (r2 + 2 * x**2)\n"),),  # noqa: E501
        ("tests/test_dispersion.py::test_distortion_equals_opencv_project_points",),
    ),
    Mutation(
        "mount-error-not-inverted",
        "the true camera sees the target through the mount error, not its inverse",
        "models/errors.py",
        (("    return SE3.from_xyz_rpy(mount[0:3], mount[3:6]).inverse() @ relative\n",
          "    return SE3.from_xyz_rpy(mount[0:3], mount[3:6]) @ relative\n"),),
        ("tests/test_dispersion.py::test_mount_error_features_are_the_true_cameras_and_the_law_keeps_the_nominal_jacobian",),
    ),
    Mutation(
        "clopper-pearson-two-sided",
        "the Clopper-Pearson bound at the two-sided level (1 + c) / 2 instead of the one-sided c",
        "analysis/campaign.py",
        (("    return float(stats.beta.ppf(confidence, failures + 1, runs - failures))\n", "    return float(stats.beta.ppf((1 + confidence) / 2, failures + 1, runs - failures))\n"),),  # noqa: E501
        ("tests/test_dispersion.py::test_clopper_pearson_equals_scipy_and_the_hand_computation",),
    ),
    Mutation(
        "campaign-seed-by-batch",
        "a run's seed taken from its position in the batch, not its run number",
        "analysis/campaign.py",
        (("    rows = [simulate_run(spec, k, simulator)[0] for k in range(start, stop)]\n", "    rows = [simulate_run(spec, k - start, simulator)[0] | {\"run\": k} for k in range(start, stop)]\n"),),  # noqa: E501
        ("tests/test_dispersion.py::test_one_and_two_workers_give_identical_datasets",),
    ),
    Mutation(
        "margin-focal-error-on-fx-only",
        "the focal-length-error margin changes the true fx and leaves fy at the controller's",
        "analysis/margins.py",
        (("            errors = replace(errors, fx=fx, fy=fx * loop.camera.aspect)\n", "            errors = replace(errors, fx=fx)\n"),),  # noqa: E501
        ("tests/test_margins.py::test_plant_error_parameters_change_their_own_entry_only",),
    ),
    Mutation(
        "report-campaign-own-confidence",
        "the report's campaign stated at 90% confidence, not the campaign's default",
        "reports/document.py",
        (('{"summary": summarize_campaign(spec, table, CONFIDENCE, P_FAIL, QUANTILE)', '{"summary": summarize_campaign(spec, table, 0.9, P_FAIL, QUANTILE)'),),  # noqa: E501
        ("tests/test_report.py::test_dispersions_section_states_the_campaigns_statement",),
    ),
    Mutation(
        "report-before-campaign-of-this-design",
        "the report's campaign before the synthesis runs the synthesised design again",
        "reports/document.py",
        (("lambda: measure_before(before, stage, bound)", "lambda: measure_before(case, stage, bound)"),),
        ("tests/test_report.py::test_dispersions_section_sets_the_design_before_the_synthesis_beside_this_one",),
    ),
    Mutation(
        "stage-keys-read-synthesized-from",
        "every kept stage keyed on [synthesized_from] too (an edit of the design before remakes them all)",
        "reports/stages.py",
        (('DISPLAY = ("name", "grid", "synthesize", "synthesized_from", "report.map")', 'DISPLAY = ("name", "grid", "synthesize", "report.map")'),),  # noqa: E501
        ("tests/test_report_stages.py::test_the_campaign_before_the_synthesis_is_remade_exactly_when_its_design_changes",),
    ),
    Mutation(
        "program-digest-without-the-step",
        "the exported program's SHA-256 leaves out the generated step (dvfc_program.c)",
        "analysis/export.py",
        (('PROGRAM = ("dvfc_controller.h", "dvfc_controller.c", "dvfc_program.h", "dvfc_program.c")', 'PROGRAM = ("dvfc_controller.h", "dvfc_controller.c", "dvfc_program.h")'),),  # noqa: E501
        ("tests/test_export.py::test_the_program_digest_names_the_program_and_nothing_beside_it",),
    ),
    Mutation(
        "report-controller-coverage-simulator-rho",
        "the report's controller section states the sampled simulator's rho as the program's (fact 22)",
        "reports/templates/report.html.j2",
        (("rho = {{ imp_point.program_rho | num(6) }}", "rho = {{ imp_point.rho | num(6) }}"),),
        ("tests/test_report.py::test_the_controller_section_states_the_exports_digest_replay_step_times_and_coverage",),
    ),
    Mutation(
        "program-statement-always-passes",
        "page 1 says the exported program is the simulated controller whatever its replay found",
        "analysis/results.py",
        (("status = StatementStatus.PASS if check[\"passed\"] else StatementStatus.FAIL", "status = StatementStatus.PASS"),),  # noqa: E501
        ("tests/test_report_text.py::test_the_programs_statement_is_the_replays_outcome",),
    ),
    Mutation(
        "program-replay-failure-passes-the-verdict",
        "a failed replay of the exported program leaves the review's verdict passing",
        "analysis/results.py",
        (("if s.status is StatementStatus.FAIL and not s.claims]", "if False]"),),
        ("tests/test_report_text.py::test_the_programs_statement_is_the_replays_outcome",),
    ),
    Mutation(
        "certify-json-key-renamed",
        "the envelope's re-check margin written under another key in dvfc certify's JSON",
        "analysis/envelope.py",
        (("    recheck_margin: float | None = None\n", "    margin: float | None = None\n"),
         ("        recheck_margin=margin,\n", "        margin=margin,\n")),
        ("tests/test_golden.py::test_each_commands_json_is_the_recorded_one[certify]",),
    ),
    Mutation(
        "true-pixels-nominal-centre",
        "the worst run's true features drawn about the controller's principal point, not the plant's",
        "analysis/campaign.py",
        (("    return f.reshape(len(traj.t), -1, 2) + np.asarray(errors.principal_point, dtype=float)\n", "    return f.reshape(len(traj.t), -1, 2) + loop.camera.centre\n"),),  # noqa: E501
        ("tests/test_dispersion.py::test_true_pixels_are_the_models_features_without_errors_and_shift_with_the_principal_point",),
    ),
    Mutation(
        "margin-mount-rotation-ignored",
        "the mount-rotation margin leaves the mount as it is, whatever the angle",
        "analysis/margins.py",
        (("            errors = replace(errors, mount_rpy=np.array([np.radians(value), 0.0, 0.0]))\n", "            pass\n"),),  # noqa: E501
        ("tests/test_margins.py::test_a_large_mount_rotation_breaks_the_loop_and_a_small_one_does_not",),
    ),
    Mutation(
        "report-campaign-runs-unbounded",
        "[report] campaign_runs accepts 0 runs",
        "analysis/schema.py",
        (("    campaign_runs: Annotated[int, Field(ge=1)] = 100\n", "    campaign_runs: int = 100\n"),),
        ("tests/test_dispersion.py::test_report_campaign_runs_is_a_strict_positive_integer",),
    ),
    # --- statements that claim more than is true (each caught against an independent computation) ---
    Mutation(
        "christoffel-distal-term-dropped",
        "fact 23's bound on dM_ij/dq_k leaves out the joints below both i and j (k > hi)",
        "models/inertia.py",
        (("                    elif k > hi:\n", "                    elif k > hi and False:\n"),),
        ("tests/test_integral_envelope.py::test_the_ur5_bounds_are_those_of_the_derivation",),
    ),
    Mutation(
        "sigma-min-without-weyl-correction",
        "fact 23's s_lo taken at the cells' centres, without Weyl's correction over each cell",
        "analysis/integral_envelope.py",
        (("        return values - np.sum(", "        return values - 0 * np.sum("),),
        ("tests/test_integral_envelope.py::test_sigma_min_on_coarse_cells_is_below_every_sampled_value",),
    ),
    Mutation(
        "inertia-cross-carrier-alpha",
        "fact 10.1's cross term with the carrier taken as a_c^T S a_c instead of |S a_c| (below |M_ic|)",
        "models/inertia.py",
        (("        alpha[0, :] = alpha[:, 0] = np.linalg.norm(spin @ a)  # |a_i^T S a_c| <= |S a_c|\n",
          "        alpha[0, :] = alpha[:, 0] = a @ spin @ a\n"),),
        ("tests/test_inertia_cross_terms.py::test_inertia_bound_dominates_mass_matrix_entrywise_with_cross_terms",),
    ),
    Mutation(
        "inertia-cross-alpha-dropped",
        "fact 10.1's rotational cross terms of the joints above the carrier dropped (lambda_max(I_L) on the diagonal only)",  # noqa: E501
        "models/inertia.py",
        (("        alpha = np.full((len(moved), len(moved)), item.principal[-1])\n",
          "        alpha = np.diag(np.full(len(moved), item.principal[-1]))\n"),),
        ("tests/test_inertia_cross_terms.py::test_inertia_bound_dominates_mass_matrix_entrywise_with_cross_terms",),
    ),
    Mutation(
        "lyapunov-margin-tenfold-looser",
        "fact 14's Lyapunov check accepts a decrease lambda_min(P - Pi^T P Pi) of 0.05 instead of 0.5",
        "analysis/multirate.py",
        (("LYAPUNOV_MARGIN = 0.5\n", "LYAPUNOV_MARGIN = 0.05\n"),),
        ("tests/test_multirate_statements.py::test_lyapunov_check_certifies_only_a_decrease_of_at_least_one_half",),
    ),
    Mutation(
        "lyapunov-tolerance-tenfold",
        "fact 14's tolerance on Pi from ten times the margin (a perturbation beyond the proof is claimed covered)",
        "analysis/multirate.py",
        (("max(margin, 0.0) / p_norm) - pi_norm", "10 * max(margin, 0.0) / p_norm) - pi_norm"),),
        ("tests/test_multirate_statements.py::test_lyapunov_tolerance_is_the_root_of_the_stated_bound_and_keeps_the_decrease",),
    ),
    Mutation(
        "multirate-saturation-any-joint",
        "fact 14 applies when any joint's g(q_eq) is inside its effort (one saturated joint passes)",
        "analysis/multirate.py",
        (("not np.all(np.abs(self.lin.tau_eq) < imp.limits(urdf).effort)",
          "not np.any(np.abs(self.lin.tau_eq) < imp.limits(urdf).effort)"),),
        ("tests/test_multirate_statements.py::test_saturation_at_the_equilibrium_torque_puts_the_loop_outside_the_statement",),
    ),
    Mutation(
        "multirate-saturation-boundary",
        "fact 14 applies with g(q_eq) exactly at an effort (on the clip's kink)",
        "analysis/multirate.py",
        (("not np.all(np.abs(self.lin.tau_eq) < imp.limits(urdf).effort)",
          "not np.all(np.abs(self.lin.tau_eq) <= imp.limits(urdf).effort)"),),
        ("tests/test_multirate_statements.py::test_an_equilibrium_torque_exactly_at_its_effort_is_outside_the_statement",),
    ),
    Mutation(
        "windows-lower-gamma-unsquared",
        "the window's lower limit with D_tau^2 / (2 gamma) instead of D_tau^2 / (2 gamma^2) (equal at gamma = 1)",
        "analysis/windows.py",
        (("0.5 * s2 + d2 / (2.0 * gamma**2)", "0.5 * s2 + d2 / (2.0 * gamma)"),),
        ("tests/test_window_limits.py::test_window_lower_limit_is_where_the_reference_xi_block_of_p_loses_definiteness",),
    ),
    Mutation(
        "windows-lower-disturbance-unsquared",
        "the window's lower limit with D_tau instead of D_tau^2 (equal at unit weights)",
        "analysis/windows.py",
        (("plant.disturbance()[:n] ** 2", "plant.disturbance()[:n]"),),
        ("tests/test_window_limits.py::test_window_lower_limit_is_where_the_reference_xi_block_of_p_loses_definiteness",),
    ),
    Mutation(
        "windows-below-inclusive",
        "a gain exactly at its open lower limit S_xi^2/2 counted inside its window (no finite gamma there)",
        "analysis/windows.py",
        (("        return self.k_xi <= self.lower\n", "        return self.k_xi < self.lower\n"),),
        ("tests/test_window_limits.py::test_a_gain_exactly_at_one_half_admits_no_finite_gamma_and_is_below_its_window",),
    ),
    Mutation(
        "windows-joint-hold-without-margin",
        "the gains together break the hold only beyond h lambda_max > 2 (the 0.05 margin dropped)",
        "analysis/windows.py",
        (("self.held is not None and self.held > 2 - self.margin", "self.held is not None and self.held > 2"),),
        ("tests/test_window_limits.py::test_together_the_gains_break_the_hold_exactly_when_the_held_map_leaves_its_margin",),
    ),
    Mutation(
        "windows-alone-without-margin",
        "a joint's hold limit alone (2 - margin) / (h (M^-1)_ii) taken as 2 / (h (M^-1)_ii)",
        "analysis/windows.py",
        (("    diagonal = (2.0 - margin) / (h * np.diag(m_inv))\n", "    diagonal = 2.0 / (h * np.diag(m_inv))\n"),),
        ("tests/test_window_limits.py::test_a_joints_limit_alone_keeps_the_margin_when_the_others_break_the_hold_already",),
    ),
    Mutation(
        "planned-level-at-the-boundary",
        "fact 16b.3 accepts c = c_max(theta_bar) (the first exit's boundary case) instead of c < c_max",
        "analysis/start.py",
        (("        if level < decay.c_max:\n", "        if level <= decay.c_max:\n"),),
        ("tests/test_start_levels.py::test_planned_start_level_lies_strictly_below_its_self_consistent_level_at_the_boundary",),
    ),
    Mutation(
        "planned-level-without-v0",
        "fact 16b.3's level c_inf,path without V(0) (a start above it claimed covered)",
        "analysis/start.py",
        (("        level = max(record[\"V0\"], c_inf)\n", "        level = c_inf\n"),),
        ("tests/test_start_levels.py::test_planned_start_level_lies_strictly_below_its_self_consistent_level_at_the_boundary",),
    ),
    Mutation(
        "path-lipschitz-radius-once",
        "fact 16b.2's Lipschitz constant with (r_hi + 1) instead of (2 r_hi + 1)",
        "analysis/start.py",
        (("** 2 * (2 * r_hi + 1) / float(", "** 2 * (r_hi + 1) / float("),),
        ("tests/test_start_levels.py::test_path_rate_slack_is_the_stated_lipschitz_constant_over_half_a_cell",),
    ),
    Mutation(
        "path-lipschitz-weight-unsquared",
        "fact 16b.2's Lipschitz constant with max(w_pc, w_rc) instead of its square",
        "analysis/start.py",
        (("max(w.w_pc, w.w_rc) ** 2 * (2 * r_hi + 1)", "max(w.w_pc, w.w_rc) * (2 * r_hi + 1)"),),
        ("tests/test_start_levels.py::test_path_rate_slack_is_the_stated_lipschitz_constant_over_half_a_cell",),
    ),
    Mutation(
        "ramp-level-without-peak",
        "fact 16a.3's level from V(0), the last step and the limit, without the recursion's peak",
        "analysis/start.py",
        (("    level = float(max(*bound, b[j] / k[j]))\n", "    level = float(max(bound[0], bound[-1], b[j] / k[j]))\n"),),  # noqa: E501
        ("tests/test_start_levels.py::test_ramp_level_bounds_every_step_of_its_recursion",),
    ),
    Mutation(
        "ramp-visible-one-step-early",
        "fact 16a.3's t_vis one step early: from the last step whose bound is above the visible level",
        "analysis/start.py",
        (("            record[\"visible_from_s\"] = times[above[-1] + 1]\n",
          "            record[\"visible_from_s\"] = times[above[-1]]\n"),),
        ("tests/test_start_levels.py::test_ramp_visibility_never_starts_before_the_last_step_above_the_visible_level",),
    ),
    Mutation(
        "envelope-level-without-v0",
        "fact 7's level c_inf for a covered start, without V(0)",
        "analysis/envelope.py",
        (("    level = max(c_inf, v0) if inside else c_inf\n", "    level = c_inf\n"),),
        ("tests/test_start_levels.py::test_envelope_level_covers_the_start_and_stays_within_the_self_consistent_level",),
    ),
    Mutation(
        "envelope-cover-unchecked",
        "fact 7's start counted covered without V(0) <= c_max(theta_bar)",
        "analysis/envelope.py",
        (("        grid = grid[design.c_max(grid) >= v0]\n", "        grid = grid\n"),
         (" and (not cover or v0 <= d.c_max):", ":")),
        ("tests/test_start_levels.py::test_envelope_level_covers_the_start_and_stays_within_the_self_consistent_level",),
    ),
    Mutation(
        "zero-failure-runs-floor",
        "the zero-failure run count rounded down (one run short of P(fail) <= p at the confidence)",
        "analysis/campaign.py",
        (("    return math.ceil(math.log(1 - confidence) / math.log(1 - p) - 1e-12)\n",
          "    return math.floor(math.log(1 - confidence) / math.log(1 - p) - 1e-12)\n"),),
        ("tests/test_campaign_statistics.py::test_zero_failure_run_count_is_the_fewest_runs_whose_clopper_pearson_bound_is_p",),
    ),
    Mutation(
        "tolerance-rank-one-low",
        "the tolerance bound's order statistic one rank lower (P(Bin(n, q) <= r) >= c instead of <= r - 1)",
        "analysis/campaign.py",
        (("stats.binom.cdf(ranks - 1, runs, quantile) >= confidence", "stats.binom.cdf(ranks, runs, quantile) >= confidence"),),  # noqa: E501
        ("tests/test_campaign_statistics.py::test_tolerance_rank_is_the_smallest_order_statistic_above_the_quantile_with_confidence",),
    ),
    Mutation(
        "dispersion-clip-upper-side-only",
        "a clipped normal redrawn only beyond +clip sigmas (the lower tail left untruncated)",
        "analysis/dispersion.py",
        (("np.any(out_of := np.abs(z) > d.clip)", "np.any(out_of := z > d.clip)"),),
        ("tests/test_campaign_statistics.py::test_a_clipped_normal_latency_is_a_truncated_normal_on_both_sides",),
    ),
    Mutation(
        "latency-domain-unbounded",
        "a dispersed latency allowed below zero (an image arriving before its capture)",
        "analysis/dispersion.py",
        (("    \"implementation.latency\": Field(\"1\", 0.0),\n", "    \"implementation.latency\": Field(\"1\"),\n"),),
        ("tests/test_campaign_statistics.py::test_a_latency_drawn_negative_is_clipped_to_zero_and_no_further",),
    ),
    Mutation(
        "field-domain-upper-side-only",
        "a drawn value clipped to its field's upper end only (a negative latency kept)",
        "analysis/dispersion.py",
        (("            value = np.clip(value, f.low, f.high)\n", "            value = np.minimum(value, f.high)\n"),),
        ("tests/test_campaign_statistics.py::test_a_latency_drawn_negative_is_clipped_to_zero_and_no_further",),
    ),
    # Integral action and friction (docs/math.md, facts 18-21).
    Mutation(
        'integral-sign-flipped',
        "the integral torque added instead of subtracted (fact 20's u_xi = -K_xi xi - K_I z_I)",
        'models/loop.py',
        (('u_xi = u_xi - gain_column(self.gains.k_i) * self.z_i',
          'u_xi = u_xi + gain_column(self.gains.k_i) * self.z_i'),),
        ('tests/test_integral.py::test_fact_20_1_the_augmented_storage_keeps_the_supply_of_43',),
    ),
    Mutation(
        'integral-storage-unhalved',
        "the integral's storage z^T K_I z without its 1/2 (fact 20.1's V_a)",
        'models/loop.py',
        (('return self.storage + self.z_i.T @ (gain_column(self.gains.k_i) * self.z_i) / 2',
          'return self.storage + self.z_i.T @ (gain_column(self.gains.k_i) * self.z_i)'),),
        ('tests/test_integral.py::test_fact_20_1_the_augmented_storage_keeps_the_supply_of_43',),
    ),
    Mutation(
        'plant-friction-left-out-of-the-supply',
        "the plant's friction left out of the torque disturbance of (36) (fact 18.1)",
        'models/loop.py',
        (('return self.tau_d - self.plant_friction + self.compensation_torque',
          'return self.tau_d + self.compensation_torque'),),
        ('tests/test_integral.py::test_fact_20_1_the_augmented_storage_keeps_the_supply_of_43',),
    ),
    Mutation(
        'compensation-on-measured-qd',
        "friction compensation on the measured qd instead of the law's qd_d (fact 19.4)",
        'models/loop.py',
        (('return friction_torque(self.qd_d, cs.DM(self.compensation), self.robot.n)',
          'return friction_torque(self.qd, cs.DM(self.compensation), self.robot.n)'),),
        ('tests/test_friction.py::test_compensation_reads_the_law_s_qd_d_never_the_measured_qd',),
    ),
    Mutation(
        'anti-windup-wrong-side',
        "anti-windup (the sample's update the program and the simulator share) stops the integration on the wrong "
        "side of the upper effort limit",
        'analysis/controller.py',
        (('cs.logic_and(tau > effort, xi < 0)',
          'cs.logic_and(tau > effort, xi > 0)'),),
        ('tests/test_integral.py::test_sampled_integral_law_equals_a_sample_by_sample_loop',),
    ),
    Mutation(
        'integral-half-period',
        'the sampled integral advances half a period a sample',
        'analysis/controller.py',
        (('return z + cs.if_else(windup, cs.DM.zeros(z.numel()), h * xi)',
          'return z + cs.if_else(windup, cs.DM.zeros(z.numel()), h / 2 * xi)'),),
        ('tests/test_integral.py::test_sampled_integral_law_equals_a_sample_by_sample_loop',),
    ),
    Mutation(
        'monodromy-integral-without-period',
        "fact 21's monodromy integrates xi without the period h",
        'analysis/multirate.py',
        (('a_z[nz - nt :] += h * self.xi',
          'a_z[nz - nt :] += self.xi'),),
        ('tests/test_integral.py::test_fact_21_monodromy_with_the_integral_equals_a_sample_by_sample_simulation',),
    ),
    Mutation(
        'monodromy-friction-slope-sign',
        "the plant's viscous friction enters fact 21's linearisation as negative damping",
        'analysis/multirate.py',
        (('a[:, n : 2 * n] -= self.b_tau @ np.diag(slope)',
          'a[:, n : 2 * n] += self.b_tau @ np.diag(slope)'),),
        ('tests/test_integral.py::test_fact_21_rho_of_the_cell_with_the_integral_and_its_viscous_friction',),
    ),
    Mutation(
        'compensation-smoothing-mismatch-ignored',
        "the residual of a compensation whose tanh smoothing differs from the plant's is taken as exact (fact 19.2)",
        'analysis/envelope.py',
        (('shape = 0.0 if eh == eps else 1.0',
          'shape = 0.0'),),
        ('tests/test_friction.py::test_fact_19_2a_an_exact_compensation_recovers_the_frictionless_envelope',),
    ),
    Mutation(
        'envelope-without-coulomb',
        "the envelope with the plant's friction leaves the Coulomb torque out of its disturbance bound (fact 18.5)",
        'analysis/envelope.py',
        (('torque = disturbance.torque + float(np.linalg.norm(bound.coulomb))',
          'torque = disturbance.torque'),),
        ('tests/test_friction.py::test_fact_18_5_the_envelope_with_the_plant_s_friction_is_vacuous_on_the_cell',),
    ),
    Mutation(
        'integral-never-on',
        'the integrator never starts (z_I stays 0: no integral action at all)',
        'models/loop.py',
        (('return cs.if_else(self.t >= self.integral_start, self.xi, cs.DM.zeros(self.robot.n))',
          'return cs.DM.zeros(self.robot.n)'),),
        ('tests/test_integral.py::test_fact_20_3_a_run_under_a_constant_torque_settles_at_zero_error_only_with_the_integral',),
    ),
    Mutation(
        'compiled-integral-gain-zeroed',
        'the compiled loop reads K_I as zero from its parameter vector',
        'analysis/parametric.py',
        (('k_i = p[after_k_i - n : after_k_i] if loop.integral else None',
          'k_i = p[after_k_i - n : after_k_i] * 0 if loop.integral else None'),),
        ('tests/test_integral.py::test_fact_20_1_the_augmented_storage_keeps_the_supply_of_43',),
    ),
    Mutation(
        'compiled-plan-hold-misread',
        "the compiled loop reads the planned start's hold from the duration's entry of its parameter vector",
        'models/loop.py',
        (('return ReferencePlan(start, goal, vector[18], vector[19], (vector[12:15], vector[15:18]))',
          'return ReferencePlan(start, goal, vector[18], vector[18], (vector[12:15], vector[15:18]))'),),
        ('tests/test_parametric.py::test_a_planned_start_takes_its_start_duration_and_hold_as_inputs',),
    ),
    Mutation(
        'compiled-integral-start-zeroed',
        'the compiled loop integrates z_I from t = 0 whatever the time integral action starts from',
        'analysis/parametric.py',
        (('changes["integral_start"] = p[after_k_i]', 'changes["integral_start"] = p[after_k_i] * 0'),),
        ('tests/test_parametric.py::test_a_planned_start_takes_its_start_duration_and_hold_as_inputs',),
    ),
    Mutation(
        'compile-batch-serial',
        "the libraries of one batch compiled one after the other (their builds add up)",
        'analysis/compile.py',
        (('ThreadPoolExecutor(max_workers=os.cpu_count() or 1) as pool', 'ThreadPoolExecutor(max_workers=1) as pool'),),
        ('tests/test_compile_cache.py::test_the_libraries_of_one_batch_are_built_at_once',),
    ),
    Mutation(
        'target-at-rest-keeps-spin',
        "verify's target at rest (w = 0 for Theorem 1, Lemma 2) keeps the scenario's spin",
        'models/target.py',
        (('return replace(self, radius=0.0, spin_rate=0.0)', 'return replace(self, radius=0.0)'),),
        ('tests/test_target.py::test_a_target_at_rest_stays_at_its_start',),
    ),
    Mutation(
        'coriolis-product-not-halved',
        "the law's C(q, qd) v taken as the whole derivative of the bias along v (twice the Christoffel product)",
        'models/robot.py',
        (('return v, cs.jtimes(self.bias, self.qd, v) / 2', 'return v, cs.jtimes(self.bias, self.qd, v)'),),
        ('tests/test_robot.py::test_the_laws_coriolis_product_is_the_christoffel_one',),
    ),
    Mutation(
        'growth-against-largest-before',
        "margins' growth rule compares the last period's level with the largest before it (a transient hides a mode)",
        'analysis/margins.py',
        (('        return self.levels[-2]', '        return max(self.levels[:-1])'),),
        ('tests/test_margins.py::test_a_transient_does_not_hide_a_growing_mode_nor_noise_make_one',),
    ),
    Mutation(
        'campaign-local-statement-silent-on-dry-friction',
        "the campaign's local verdicts stated with no word of the dry friction's bound they rest on",
        'analysis/campaign.py',
        (('    return errors is not None and (drawn or errors.has_dry_friction)',
          '    return False'),),
        ('tests/test_campaign_statistics.py::test_a_local_verdict_on_dry_friction_names_its_bounded_torque_and_no_smoothing',),
    ),
    Mutation(
        'compiled-dae-differences-coarse-step',
        "a compiled function that CVODES differentiates is differenced at a step of 0.01 (its Jacobian 1e-2 off)",
        'analysis/compile.py',
        (('"fd_method": "forward"}', '"fd_method": "forward", "fd_options": {"h": 1e-2, "h_iter": 0}}'),),
        ('tests/test_compile_cache.py::test_a_differentiable_library_has_the_symbolic_jacobian_to_differences_accuracy',),
    ),
    Mutation(
        'rosenbrock-w-without-friction',
        "ROS34PW2's stages solve with M alone: the friction's slope left out of W (an explicit step on a stiff flow)",
        'analysis/rosenbrock.py',
        (('    system = mass + h * GAMMA * cs.diag(slope)', '    system = mass'),),
        ('tests/test_rosenbrock.py::test_fact_28_2_one_step_is_stable_and_accurate_at_any_friction_slope',
         'tests/test_rosenbrock.py::test_wrist_3_released_from_rest_with_one_step_a_period_matches_sixteen'),
    ),
    Mutation(
        'rosenbrock-coupling-dropped',
        "ROS34PW2's stage coupling h W sum_j gamma_ij k_j left out of the speeds (the method's order lost)",
        'analysis/rosenbrock.py',
        (('h * (mass @ f[n : 2 * n]) - h * slope * v)', 'h * (mass @ f[n : 2 * n]))'),),
        ('tests/test_rosenbrock.py::test_fact_28_1_ros34pw2_is_of_order_3_whatever_its_w',),
    ),
    Mutation(
        'auto-integrates-dry-friction-by-rk4',
        'integrator "auto" takes RK4 for a plant with dry friction too',
        'analysis/implementation.py',
        (('            return "rosenbrock" if dry_friction else "rk4"', '            return "rk4"'),),
        ('tests/test_rosenbrock.py::test_auto_integrates_dry_friction_by_ros34pw2_and_no_friction_by_rk4',
         'tests/test_rosenbrock.py::test_wrist_3_released_from_rest_with_one_step_a_period_matches_sixteen'),
    ),
    Mutation(
        'rosenbrock-embedded-estimate-zero',
        "ROS34PW2's local error estimate taken with the step's own weights for the embedded ones (always 0)",
        'analysis/rosenbrock.py',
        (('    error = sum((b - bhat) * k for b, bhat, k', '    error = sum((b - b) * k for b, bhat, k'),),
        ('tests/test_rosenbrock.py::test_fact_28_4_the_embedded_estimate_measures_the_local_error',
         'tests/test_rosenbrock.py::test_wrist_3_released_from_rest_with_one_step_a_period_matches_sixteen'),
    ),
    Mutation(
        'run-local-error-not-stated',
        "a run by ROS34PW2 does not record its largest local error estimate",
        'analysis/sampled.py',
        (('    return {"local_error_q": float(np.nanmax(values))} if np.isfinite(values).any() else {}',
          '    return {}'),),
        ('tests/test_rosenbrock.py::test_wrist_3_released_from_rest_with_one_step_a_period_matches_sixteen',),
    ),
    Mutation(
        'campaign-null-column-untyped',
        "a campaign batch whose runs have no value in a column keeps it typed null (the dataset no longer reads)",
        'analysis/campaign.py',
        (('    return table.cast(pa.schema(fields))', '    return table'),),
        ('tests/test_dispersion.py::test_a_batch_whose_runs_have_no_local_error_reads_with_the_others',),
    ),
    Mutation(
        'sampled-cvodes-dae-interpreted',
        "the sampled loop's CVODES period runs the DAE by CasADi's virtual machine under jit",
        'analysis/sampled.py',
        (('        if "dae" in own:\n            self.dae = own["dae"]',
          '        if False:\n            self.dae = own["dae"]'),),
        ('tests/test_sampled.py::test_cvodes_between_samples_runs_the_compiled_dae_under_jit',),
    ),
    Mutation(
        'compile-ahead-at-full-priority',
        "the compilers of builds started ahead run at the process's own priority (they slow the builds waited for)",
        'analysis/compile.py',
        ((', initializer=_lowest_priority)', ')'),),
        ('tests/test_compile_cache.py::test_a_build_started_ahead_runs_at_the_lowest_priority_and_is_waited_for_not_repeated',),
    ),
    Mutation(
        'compile-ahead-waits',
        "within ahead, compiled_together builds and waits (the builds it should overlap add up)",
        'analysis/compile.py',
        (('    if _ahead.is_set():\n', '    if False:\n'),),
        ('tests/test_compile_cache.py::test_a_build_started_ahead_runs_at_the_lowest_priority_and_is_waited_for_not_repeated',),
    ),
    Mutation(
        'compile-child-keeps-parents-builds',
        "a forked child takes its parent's builds in flight for its own (it waits for threads it does not have)",
        'analysis/compile.py',
        (('    _building.clear()\n\n\nos.register_at_fork', '\n\nos.register_at_fork'),),
        ('tests/test_compile_cache.py::test_a_child_forked_while_a_build_runs_ahead_waits_for_its_library_and_loads_it',),
    ),
    Mutation(
        'margins-range-end-said-whole-range',
        "a search whose one run, at the searched range's end, holds says the loop holds over the whole range",
        'analysis/margins.py',
        (('ENDS_HOLDING = "its run at the searched range\'s end holds (no value between is run: the loop may break '
          'between)"', 'ENDS_HOLDING = "holds over the whole searched range"'),),
        ('tests/test_margins.py::test_a_search_whose_ranges_end_holds_says_it_ran_that_value_only',),
    ),
    Mutation(
        'urdf-origin-less-inertial-refused',
        "an <inertial> or a joint without <origin> passed to the parser as it is (which refuses it)",
        'models/robot.py',
        (('        if element.find("origin") is None:\n', '        if False:\n'),),
        ('tests/test_robot.py::test_an_inertial_or_joint_without_origin_is_the_identity_and_geometry_is_not_read',),
    ),
    Mutation(
        'urdf-geometry-read',
        "a link's visual and collision elements passed to the parser (it prints a line for each tag it does not know)",
        'models/robot.py',
        (('[*link.findall("visual"), *link.findall("collision")]', '[]'),),
        ('tests/test_robot.py::test_an_inertial_or_joint_without_origin_is_the_identity_and_geometry_is_not_read',),
    ),
    Mutation(
        "dry-friction-kernel-reversed",
        "fact 29's input kernel taken in time order: the friction early in a period weighted as if late",
        "analysis/dry_friction.py",
        (("    return np.array(gamma[::-1]), np.array(slope[::-1])\n",
          "    return np.array(gamma), np.array(slope[::-1])\n"),),
        ("tests/test_dry_friction.py::test_fact_29_the_worst_friction_over_two_periods_drives_the_sum_of_its_terms",),
    ),
    Mutation(
        "dry-friction-input-through-the-plant",
        "fact 29's period input passed through one more period map before it is added to z",
        "analysis/dry_friction.py",
        (("        z[:, size + k * nz : size + (k + 1) * nz] += np.eye(nz)\n",
          "        z[:, size + k * nz : size + (k + 1) * nz] += a_z\n"),),
        ("tests/test_dry_friction.py::test_fact_29_the_worst_friction_over_two_periods_drives_the_sum_of_its_terms",),
    ),
    Mutation(
        "dry-friction-no-excess",
        "fact 29's upper bound without the excess of int |g| over |int g| on a part (the lower bound for every torque)",
        "analysis/dry_friction.py",
        (("    kernel = np.concatenate([gamma, delta**2 / 3 * slope], axis=2)",
          "    kernel = np.concatenate([gamma, 0 * slope], axis=2)"),),
        ("tests/test_dry_friction.py::test_fact_29_the_bounds_close_in_on_the_supremum_as_the_parts_shrink",),
    ),
    Mutation(
        "dry-friction-sum-truncated",
        "fact 29's sum stopped after three common periods whatever the rest",
        "analysis/dry_friction.py",
        (("        if np.all(tail <= TAIL * lower.max(axis=0)) or periods",
          "        if periods >= 3 or periods"),),
        ("tests/test_dry_friction.py::test_fact_29_the_bounds_close_in_on_the_supremum_as_the_parts_shrink",),
    ),
    Mutation(
        "verdict-smoothed-coulomb-slope",
        "fact 14's verdict linearising the smoothed dry friction's slope b + c/eps again (a verdict set by eps)",
        "analysis/multirate.py",
        (("        return None if e is None or not np.any(e.viscous) else np.asarray(e.viscous, dtype=float)\n",
          "        return None if e is None else np.asarray(e.viscous, dtype=float) + "
          "np.asarray(e.coulomb) / e.smoothing\n"),),
        ("tests/test_dry_friction.py::test_fact_29_a_draws_verdict_does_not_depend_on_the_smoothing_width",),
    ),
    Mutation(
        "verdict-ignores-dry-friction",
        "a plant with dry friction certified by rho alone, whatever the tracking error its friction can hold at rest",
        "analysis/multirate.py",
        (("    if certified and plant.coulomb is not None:\n", "    if False:\n"),),
        ("tests/test_dry_friction.py::test_fact_29_a_plant_whose_dry_friction_can_hold_the_error_beyond_the_criterion_is_not_certified",),
    ),
    Mutation(
        "dry-friction-angle-unjudged",
        "fact 29's check against the criterion reading the position only",
        "analysis/dry_friction.py",
        (("    return position <= criterion[0] and angle_deg <= criterion[1]\n",
          "    return position <= criterion[0]\n"),),
        ("tests/test_dry_friction.py::test_fact_29_a_plant_whose_dry_friction_can_hold_the_error_beyond_the_criterion_is_not_certified",),
    ),
    Mutation(
        "dry-friction-offset-dropped",
        "fact 29's tracking error at rest without the equilibrium's own error",
        "analysis/dry_friction.py",
        (("    return position + float(np.linalg.norm(upper[:3])), "
          "math.degrees(angle + float(np.linalg.norm(upper[3:])))\n",
          "    return float(np.linalg.norm(upper[:3])), math.degrees(float(np.linalg.norm(upper[3:])))\n"),),
        ("tests/test_dry_friction.py::test_fact_29_the_tracking_error_at_rest_counts_the_equilibriums_own",),
    ),
    Mutation(
        "interned-arm-ignores-urdf-text",
        "an arm found again by its URDF's path alone: an edited URDF (another mass) keeps the arm built before it",
        "analysis/scenario.py",
        (("        key = (\"robot\", str(urdf), urdf.read_bytes(), frame, section.mount.model_dump_json(), armature)\n",
          "        key = (\"robot\", str(urdf), frame, section.mount.model_dump_json(), armature)\n"),),
        ("tests/test_parametric.py::test_a_scenario_rebuilt_with_other_numbers_shares_its_arm_camera_and_structure",),
    ),
    Mutation(
        "interned-camera-ignores-focal-length",
        "a camera found again without its focal length: another focal length keeps the camera built before it",
        "analysis/scenario.py",
        (("    key = (\"camera\", camera.focal_length, camera.points.tobytes(),",
          "    key = (\"camera\", camera.points.tobytes(),"),),
        ("tests/test_parametric.py::test_a_scenario_rebuilt_with_other_numbers_shares_its_arm_camera_and_structure",),
    ),
    Mutation(
        'campaign-synthesis-checks-ignore-saturation',
        "the campaign synthesis' checks pass a design whose hold torque saturates at rest",
        'analysis/cell.py',
        (('    return Checks(outside, gamma, verdict.rho, margin, verdict.certified)',
          '    return Checks(outside, gamma, 0.9 if verdict.saturated else verdict.rho, margin,\n'
          '                  verdict.certified or verdict.saturated)'),),
        ('tests/test_cell.py::test_a_design_whose_hold_torque_saturates_does_not_pass',),
    ),
    Mutation(
        'pool-stopped-without-interrupting-its-workers',
        'a stopped job waits for its workers to finish their running tasks',
        'analysis/tasks.py',
        (('            stack.push(lambda kind, *_: kind is not None and _interrupt_workers(pool))',
          '            stack.push(lambda kind, *_: False)'),),
        ('tests/test_tasks.py::test_stopping_early_stops_the_workers_running_tasks_and_starts_no_queued_one',),
    ),
    Mutation(
        'worker-swallows-ctrl-c',
        "a worker remembers Ctrl-C but lets its running task go on",
        'analysis/output.py',
        (('        if first and _IN_TASK.is_set():\n            raise KeyboardInterrupt',
          '        if first and _IN_TASK.is_set():\n            pass'),),
        ('tests/test_tasks.py::test_stopping_early_stops_the_workers_running_tasks_and_starts_no_queued_one',),
    ),
    Mutation(
        'fact-14-draw-linearised-at-the-models-masses',
        "fact 14 for a drawn plant evaluates the structure's functions at the controller model's masses",
        'analysis/multirate.py',
        (('    p = parameter_vector(rest)\n',
          '    p = parameter_vector(rest if rest.plant is None else replace(rest, plant=loop.robot))\n'),),
        ('tests/test_multirate.py::test_a_draws_plant_linearises_on_the_structures_functions',),
    ),
    Mutation(
        'compiled-rest-run-sinusoid-parts-swapped',
        "the run from rest reads its worst sinusoid's cosine and sine parts swapped from the parameter vector",
        'models/driven.py',
        (('return Sinusoid(vector[:size], vector[size : 2 * size], vector[2 * size])',
          'return Sinusoid(vector[size : 2 * size], vector[:size], vector[2 * size])'),),
        ('tests/test_parametric.py::test_a_run_from_rest_takes_its_sinusoid_as_an_input',),
    ),
    # A user's URDF, calibration file and units; the start's inverse kinematics.
    Mutation(
        'urdf-zero-effort-accepted',
        "an effort limit of 0 accepted as a limit (a run 'within' a 0 N m limit)",
        'models/robot.py',
        (('and value <= 0):',
          'and value < 0):'),),
        ('tests/test_own_arm.py::test_a_zero_negative_or_missing_effort_or_velocity_limit_is_refused_naming_the_joint',),
    ),
    Mutation(
        'urdf-massless-link-through-fixed-child',
        "a moving link's inertia found only on itself, not on what is fixed to it",
        'models/robot.py',
        (('return link in heavy or any(carries(child) for child in rigid.get(link, ()))',
          'return link in heavy'),),
        ('tests/test_own_arm.py::test_moving_links_without_inertial_data_are_refused_naming_them',),
    ),
    Mutation(
        'urdf-continuous-joint-limited',
        "a continuous joint's lower/upper read as position limits",
        'models/robot.py',
        (('if key in ("lower", "upper") and (text is None or kind == "continuous"):',
          'if key in ("lower", "upper") and text is None:'),),
        ('tests/test_own_arm.py::test_a_continuous_joint_has_no_position_limits_and_may_give_no_effort_or_velocity',),
    ),
    Mutation(
        'calibration-rational-terms-ignored',
        "a rational model's nonzero k4-k6 accepted as the 5-coefficient model",
        'analysis/calibration.py',
        (('if d.size > 5 and np.any(d[5:]):',
          'if d.size > 8 and np.any(d[5:]):'),),
        ('tests/test_own_arm.py::test_a_bad_calibration_file_is_one_line_naming_the_file_and_the_field',),
    ),
    Mutation(
        'angle-unit-check-one-sided',
        'an angle of -180 (degrees) accepted: only positive angles checked against 2 pi',
        'analysis/schema.py',
        (('    if abs(value) > 2 * math.pi:',
          '    if value > 2 * math.pi:'),),
        ('tests/test_own_arm.py::test_a_length_in_mm_or_an_angle_in_degrees_or_a_latency_in_ms_is_flagged_naming_the_field',),
    ),
    Mutation(
        'ik-conditioned-solution-kept-off-goal',
        'the start search keeps a better-conditioned configuration that lost the goal',
        'analysis/ik.py',
        (('for y in (x, near) if max',
          'for y in (x,) if max'),),
        ('tests/test_ik.py::test_a_solution_whose_conditioning_loses_the_goal_is_kept_as_least_squares_found_it',),
    ),
    Mutation(
        'ik-box-past-one-sided-limit',
        "the start search's box moved past a joint's one-sided limit",
        'analysis/ik.py',
        (('return lower + np.where(finite_low, margin, 0.0), upper - np.where(finite_high, margin, 0.0)',
          'return lower + margin, upper - margin'),),
        ('tests/test_ik.py::test_the_search_box_keeps_every_limit_and_a_full_turn_where_there_is_none',),
    ),
    Mutation(
        'ik-no-global-fallback',
        'the start search gives up after its local starts (no global screening)',
        'analysis/ik.py',
        (('    for stage in (local, None):',
          '    for stage in (local,):'),),
        ('tests/test_ik.py::test_the_global_search_finds_a_configuration_the_local_starts_miss',),
    ),
    # The sampled loop's step-size choice and the checks' round-off tolerances.
    Mutation(
        'auto-substeps-target-tightened',
        'the substep choice demands 100x the stated error target (more steps than needed)',
        'analysis/sampled.py',
        (('if estimate <= imp.step_error or k == MAX_AUTO_SUBSTEPS:',
          'if estimate <= imp.step_error / 100 or k == MAX_AUTO_SUBSTEPS:'),),
        ('tests/test_sampled.py::test_auto_chooses_the_fewest_steps_meeting_the_target',),
    ),
    Mutation(
        'auto-substeps-target-loosened',
        'the substep choice accepts 100x the stated error target',
        'analysis/sampled.py',
        (('if estimate <= imp.step_error or k == MAX_AUTO_SUBSTEPS:',
          'if estimate <= imp.step_error * 100 or k == MAX_AUTO_SUBSTEPS:'),),
        ('tests/test_sampled.py::test_auto_substeps_bring_fact_11_within_its_tolerance_where_one_step_does_not',),
    ),
    Mutation(
        'step-doubling-estimate-wrong-order',
        "step doubling's Richardson factor for a fourth-order method misread (gap/16 for 16/15 gap)",
        'analysis/sampled.py',
        (('return 0.0 if gap == 0 else 2**order / (2**order - 1) * gap / change if change > 0 else math.inf',
          'return 0.0 if gap == 0 else gap / change / 2**order if change > 0 else math.inf'),),
        ('tests/test_sampled.py::test_auto_chooses_the_fewest_steps_meeting_the_target',),
    ),
    Mutation(
        'substeps-chosen-per-run',
        "a campaign's copies choose their substeps anew for every run",
        'analysis/sampled.py',
        (('        if self._periods.period is None:',
          '        if True:'),),
        ('tests/test_sampled.py::test_a_campaign_simulator_chooses_once_for_all_its_runs',),
    ),
    Mutation(
        'explicit-substeps-overridden',
        'an explicit substeps setting replaced by the automatic choice',
        'analysis/sampled.py',
        (('        if self._method is not None and self.implementation.substeps == "auto":',
          '        if self._method is not None:'),),
        ('tests/test_sampled.py::test_explicit_substeps_are_run_as_given',),
    ),
    Mutation(
        'fact-11-fix-step-error-unscaled',
        "fact 11's failure suggests a step_error that does not fix it",
        'analysis/verify.py',
        (('setting += f" or step_error <= {4 * choice.estimate / 16**doublings:.1g}"',
          'setting += f" or step_error <= {4 * choice.estimate:.1g}"'),),
        ('tests/test_sampled.py::test_a_fact_11_failure_from_truncation_names_the_setting_that_fixes_it',),
    ),
    Mutation(
        'fact-11-fix-substeps-one-doubling-short',
        "fact 11's failure suggests one doubling of substeps too few",
        'analysis/verify.py',
        (('    finer = k * 2**doublings',
          '    finer = k * 2 ** (doublings - 1)'),),
        ('tests/test_sampled.py::test_a_fact_11_failure_from_truncation_names_the_setting_that_fixes_it',),
    ),
    Mutation(
        'theorem-2-integral-roundoff-loosened',
        "the round-off tolerance of verify's comparisons loosened to 1e-8 of the terms (hides a real violation)",
        'analysis/verify.py',
        (('ROUNDOFF = 1e-12',
          'ROUNDOFF = 1e-8'),),
        ('tests/test_verify.py::test_theorem_2_integral_claim_tolerates_round_off_and_no_more',),
    ),
    Mutation(
        'gain-claim-without-roundoff',
        'the measured gain compared with gamma with no round-off allowance',
        'analysis/verify.py',
        (('f"<= {gamma:.6g}", ratio <= gamma + roundoff(gamma, ratio), run),',
          'f"<= {gamma:.6g}", ratio <= gamma, run),'),),
        ('tests/test_verify.py::test_theorem_2_integral_claim_tolerates_round_off_and_no_more',),
    ),
    # Measured margins held to fact 14; synthesis inside the windows with margin; the start decided once.
    Mutation(
        'margin-ignores-linear-instability',
        'a run where the linearised sampled loop is unstable (fact 14) judged by its run alone',
        'analysis/margins.py',
        (('    unstable = rho is not None and rho >= 1 - RHO_MARGIN',
          '    unstable = False'),),
        ('tests/test_margins.py::test_a_latency_where_the_linearised_loop_is_unstable_does_not_hold_though_its_run_does',),
    ),
    Mutation(
        'growth-at-threshold-not-growing',
        'an error envelope growing by exactly the stated factor read as steady',
        'analysis/margins.py',
        (('        return self.ratio > self.limit',
          '        return self.ratio >= self.limit'),),
        ('tests/test_margins.py::test_the_error_envelope_grows_only_when_the_error_grows',),
    ),
    Mutation(
        'growth-judged-on-too-few-periods',
        "a run's growth judged on fewer whole periods of the target's motion than stated (one after the first)",
        'analysis/margins.py',
        (('    if count < PERIODS:\n', '    if count < 1:\n'),),
        ('tests/test_margins.py::test_the_error_envelope_grows_only_when_the_error_grows',),
    ),
    Mutation(
        'growth-rate-above-a-slow-divergence',
        'the growth threshold 0.03 1/s, above the 0.02 1/s of rho = 1 + 1e-3 per 50 ms',
        'analysis/margins.py',
        (('GROWTH_RATE = 0.01\n', 'GROWTH_RATE = 0.03\n'),),
        ('tests/test_margins.py::test_the_error_envelope_grows_only_when_the_error_grows',
         'tests/test_margins.py::test_a_loop_just_past_its_linear_margin_fails_the_steady_state_check_alone'),
    ),
    Mutation(
        'margin-clipped-wrong-way',
        "a measured margin beyond fact 14's linear one reported unclipped",
        'analysis/margins.py',
        (('    beyond = lambda v: v is None or (v > m["stable_at"] if p.worse == "up" else v < m["stable_at"])',
          '    beyond = lambda v: v is None or (v < m["stable_at"] if p.worse == "up" else v > m["stable_at"])'),),
        ('tests/test_margins.py::test_a_measured_margin_beyond_the_linear_one_is_clipped_to_it',),
    ),
    Mutation(
        'payload-range-fixed',
        'the payload margin searched over a fixed range whatever the arm',
        'analysis/margins.py',
        (('    end = p.end * urdf_mass(loop.robot) if p.per_arm_mass else p.end',
          '    end = p.end'),),
        ('tests/test_margins.py::test_the_payload_range_scales_with_the_arms_mass',),
    ),
    Mutation(
        'synthesis-hold-bound-per-entry',
        "the synthesis's hold bound K_xi <= 0.8 1.95 M/h as an entrywise instead of a matrix inequality",
        'analysis/synthesize.py',
        (('        constraints.append(hold - cp.diag(k_xi) >> 0)',
          '        constraints.append(cp.diag(hold) - k_xi >= 0)'),),
        ('tests/test_synthesize.py::test_the_target_speed_sdp_keeps_every_gain_inside_its_window_with_margin',),
    ),
    Mutation(
        'compile-cache-unlocked',
        "a cache entry built without its lock: processes needing the same library at once each build it",
        'analysis/compile.py',
        (('    fcntl.flock(handle, fcntl.LOCK_EX)\n', '    pass\n'),),
        ('tests/test_compile_cache.py::test_processes_needing_one_library_at_once_build_it_once',),
    ),
    Mutation(
        'compile-cache-hit-generates-c',
        "a cache hit generates the function's C again (the entry keyed as if by its source)",
        'analysis/compile.py',
        (('    if library in _building or library.exists():\n', '    if library in _building:\n'),
         ('    if library.exists():  # built while', '    if False:  # built while')),
        ('tests/test_compile_cache.py::test_a_cache_hit_generates_no_c_source',),
    ),
    Mutation(
        'continued-run-restarts-its-integrals',
        "a run continued from a shorter one (the horizon search from rest) starts its integrals from zero again",
        'analysis/simulate.py',
        (('            integrals[:, : k + 1] = np.array([after.integrals[name] for name in QUADRATURES])\n', ''),),
        ('tests/test_theorem2.py::test_a_continued_run_from_rest_is_the_run_made_at_once',),
    ),
    Mutation(
        'local-verdict-rho-alone',
        "fact 14's one verdict on a plant reads the spectral radius alone (the self-motion's and Lyapunov checks "
        "dropped)",
        'analysis/multirate.py',
        (('    certified = rho < 1 - RHO_MARGIN and across.certified(check)\n    reason = (f"rho = {rho:.6g}, the',
          '    certified = rho < 1 - RHO_MARGIN\n    reason = (f"rho = {rho:.6g}, the'),),
        ('tests/test_local_verdict.py::test_a_payload_that_moves_the_self_motion_is_certified_nowhere',),
    ),
    Mutation(
        'synthesis-design-from-the-solvers-face',
        "the minimum-gamma design is the solver's point on the optimal face, not the box's corner (machine-dependent)",
        'analysis/synthesize.py',
        (('    if isinstance(s, cp.Variable):  # no target', '    if False:  # no target'),),
        ('tests/test_synthesize.py::test_the_design_is_the_same_when_the_data_move_by_round_off',),
    ),
    Mutation(
        'synthesis-corner-past-the-hold',
        "the corner's K_xi left at the box's upper bounds, past the windows' hold LMI",
        'analysis/synthesize.py',
        (('        upper *= min(1.0, float(np.linalg.eigvalsh(root[:, None] * hold * root[None, :])[0]))',
          '        upper *= min(1.0, float(np.linalg.eigvalsh(root[:, None] * hold * root[None, :])[-1]))'),),
        ('tests/test_synthesize.py::test_the_sdp_keeps_every_gain_inside_its_window_with_margin',),
    ),
    Mutation(
        'synthesis-start-taken-from-envelope',
        "the envelope's statement not re-derived from the start record (inside, though the start statement says not)",
        'analysis/envelope.py',
        (('    env = replace(env, start=start)',
          '    env = replace(env)'),),
        ('tests/test_start.py::test_a_start_the_planned_reference_does_not_certify_is_inside_in_no_output',),
    ),
    Mutation(
        'synthesis-rounding-outward',
        'synthesised gains rounded to the nearest figures even past their upper bound',
        'analysis/synthesize.py',
        (('    for digits, rounder in itertools.product(range(3, 9), (_round, _round_down)):',
          '    for digits, rounder in itertools.product(range(3, 9), (_round,)):'),),
        ('tests/test_synthesize.py::test_gains_on_an_upper_bound_round_toward_zero_to_three_figures',),
    ),
    # The controller as the program that runs: its discrete observer, its safe outputs, its C step.
    Mutation(
        'program-observer-camera-velocity-sign',
        "the program's observer steps the camera velocity the wrong way (fact 22)",
        'models/loop.py',
        (('before, after = SE3.exp(-h * v_wc), SE3.exp(h * u_e)',
          'before, after = SE3.exp(h * v_wc), SE3.exp(h * u_e)'),),
        ('tests/test_controller.py::test_observer_step_is_the_exact_flow_of_12_for_held_velocities',),
    ),
    Mutation(
        'program-quaternion-step-sign',
        "the program's quaternion step of the camera's rotation the wrong way (fact 22)",
        'models/loop.py',
        (('quaternion_exp(-h * v_wc[3:6])',
          'quaternion_exp(h * v_wc[3:6])'),),
        ('tests/test_controller.py::test_observer_step_is_the_exact_flow_of_12_for_held_velocities',),
    ),
    Mutation(
        'program-image-with-current-estimate',
        'the image read with the current estimate instead of the estimate of its capture time',
        'analysis/controller.py',
        (('e_new, readable = image_update(loop)(at_capture, features)',
          'e_new, readable = image_update(loop)(gbar, features)'),),
        ('tests/test_controller.py::test_image_is_read_with_the_estimate_of_its_capture_time',),
    ),
    Mutation(
        'program-image-gate-loosened',
        'an image estimate ten times the standoff accepted',
        'analysis/controller.py',
        (('cs.norm_2(e_e[0:3]) <= standoff',
          'cs.norm_2(e_e[0:3]) <= 10 * standoff'),),
        ('tests/test_controller.py::test_a_bad_image_is_dropped_like_a_lost_frame',),
    ),
    Mutation(
        'program-capture-outside-ring',
        "an image captured one sample before the ring's oldest estimate accepted",
        'analysis/controller.py',
        (('capture > k - layout.ring)',
          'capture >= k - layout.ring)'),),
        ('tests/test_controller.py::test_a_bad_image_is_dropped_like_a_lost_frame',),
    ),
    Mutation(
        'program-nonfinite-estimate-passes',
        "a non-finite estimate at finite joints gives the law's (non-finite) torque",
        'analysis/controller.py',
        (('[cs.if_else(fine, tau, gravity), x_next, status]',
          '[cs.if_else(joints, tau, gravity), x_next, status]'),),
        ('tests/test_controller.py::test_a_non_finite_estimate_gives_gravity_compensation_at_q',),
    ),
    Mutation(
        'program-integral-state-ignored',
        "the program's law reads its integral state as zero",
        'analysis/controller.py',
        (('cs.vertcat(q, qd, gbar, z_i) if loop.integral',
          'cs.vertcat(q, qd, gbar, 0 * z_i) if loop.integral'),),
        ('tests/test_controller.py::test_integral_action_of_the_program_is_the_sampled_simulators_rule',),
    ),
    Mutation(
        'program-without-anti-windup',
        'the program (and the sampled simulator, its update) integrates through saturation',
        'analysis/controller.py',
        (('return z + cs.if_else(windup, cs.DM.zeros(z.numel()), h * xi)',
          'return z + h * xi'),),
        ('tests/test_integral.py::test_sampled_integral_law_equals_a_sample_by_sample_loop',),
    ),
    Mutation(
        'program-without-compensation',
        "the program's law without its friction compensation",
        'analysis/controller.py',
        (('law = cs.Function("dvfc_law", arguments, [loop.tau,',
          'law = cs.Function("dvfc_law", arguments, [loop.paper_torque,'),),
        ('tests/test_controller.py::test_friction_compensation_of_the_program_is_the_sampled_simulators_law',),
    ),
    Mutation(
        'program-monodromy-ring-off-by-one',
        "the program's monodromy stores the estimate one ring slot off",
        'analysis/multirate.py',
        (('layout.slot((k - a) % ring)] = project',
          'layout.slot((k - a + 1) % ring)] = project'),),
        ('tests/test_multirate_program.py::test_program_monodromy_squared_equals_a_sample_by_sample_simulation',),
    ),
    # The program's safe output at non-finite joints.
    Mutation(
        'program-gravity-at-nonfinite-q',
        'gravity compensation evaluated at the non-finite q instead of the last finite one',
        'analysis/controller.py',
        (('q_safe = cs.if_else(_finite(q), q, x[layout.q_last])',
          'q_safe = cs.if_else(joints, q, x[layout.q_last])'),),
        ('tests/test_controller.py::test_non_finite_joints_give_gravity_compensation_at_the_last_finite_q',),
    ),
    # The loop as implemented runs the program: one sample update, the observer's held inputs (facts 11, 14, 22).
    Mutation(
        'fact-11-without-observer-term',
        "fact 11's identity checked without the observer's hold int o (11.2)",
        'analysis/verify.py',
        ((' - i["unmodelled_supply"] - i["observer_supply"]', ' - i["unmodelled_supply"]'),),
        ('tests/test_sampled.py::test_auto_substeps_bring_fact_11_within_its_tolerance_where_one_step_does_not',),
    ),
    Mutation(
        'observer-term-without-reference-rate',
        "(11.2)'s o without xi^T M (qdd_d - qdd_d^o), the law's feedforward along (12) not the observer's path",
        'models/loop.py',
        (('return nu_e.T @ self.observer_input_error + self.xi.T @ self.robot.mass_matrix @ (self.qdd_d - along)',
          'return nu_e.T @ self.observer_input_error'),),
        ('tests/test_sampled.py::test_fact_11_observer_term_closes_the_storage_rate_pointwise',),
    ),
    Mutation(
        'observer-inputs-not-held',
        'between samples the observer follows (12) on the continuous qd(t), not its held inputs (fact 22)',
        'models/loop.py',
        (('return self._estimate_rate(self.observer_velocity) if self.sampled else self.estimate_rate',
          'return self.estimate_rate'),),
        ('tests/test_sampled.py::test_fact_11_observer_term_closes_the_storage_rate_pointwise',),
    ),
    Mutation(
        'sample-update-observer-without-correction',
        "the sample's observer step (the program's and the simulator's) without its correction u_e",
        'analysis/controller.py',
        (('estimate = step(s, v_wc, u_e)', 'estimate = step(s, v_wc, 0 * u_e)'),),
        ('tests/test_sampled.py::test_sampled_run_equals_a_sample_by_sample_loop',),
    ),
    Mutation(
        'multirate-observer-inputs-dropped',
        "fact 14's period map without the observer's held inputs G_o O (the observer at rest between samples)",
        'analysis/multirate.py',
        (('a_z, a_e = phi + g_tau @ self.f + g_o @ self.o, g_tau @ self.f_e + g_e + g_o @ self.o_e',
          'a_z, a_e = phi + g_tau @ self.f, g_tau @ self.f_e + g_e'),),
        ('tests/test_multirate.py::test_monodromy_equals_a_sample_by_sample_simulation_of_the_linearised_loop',),
    ),
    Mutation(
        'simulator-uses-implausible-images',
        'the sampled simulator uses an image the program drops (e_e beyond the standoff)',
        'analysis/sampled.py',
        (('return (e_image.ravel() if usable.ravel()[0] else None), None', 'return e_image.ravel(), None'),),
        ('tests/test_sil.py::test_an_implausible_image_is_dropped_by_the_simulator_as_by_the_program',),
    ),
    # The review's verdict and the solved start.
    Mutation(
        'verdict-hides-uncertified-statements',
        'the verdict lists no statement that is not certified (the terminal says every check passes)',
        'analysis/results.py',
        (('    not_here = (StatementStatus.NOT_CERTIFIED, StatementStatus.DOES_NOT_APPLY)',
          '    not_here = (StatementStatus.NOT_CERTIFIED,)'),),
        ('tests/test_report_text.py::test_the_verdict_names_every_statement_not_certified_or_not_applying',),
    ),
    Mutation(
        'solved-start-turn-unchecked',
        "a solved start moved by whole turns even past the joint's limits",
        'analysis/ik.py',
        (('    return np.where(inside, moved, q)',
          '    return moved'),),
        ('tests/test_ik.py::test_a_solved_start_is_the_turn_of_each_angle_nearest_the_middle_of_its_range',),
    ),
    Mutation(
        'integral-start-certified-from-zero',
        "fact 20.6's start kept certified when integral action engages at t = 0 (nothing before z_I moves)",
        'analysis/start.py',
        (('    if t_i <= 0:\n        reason = (',
          '    if t_i < 0:\n        reason = ('),),
        ('tests/test_integral.py::test_fact_20_6_the_start_is_certified_until_integral_action_engages',),
    ),
    Mutation(
        'synthesis-drops-integral-action',
        "the gain synthesis runs and checks its designs without the scenario's integral action",
        'analysis/synthesize.py',
        (('    gains = Gains(point.k_xi, point.k_c, point.k_e, integral_gain(case.scenario.gains, point.k_xi))',
          '    gains = Gains(point.k_xi, point.k_c, point.k_e)'),),
        ('tests/test_cli.py::test_synthesize_keeps_the_users_file_and_certifies_the_rounded_gains',),
    ),
    Mutation(
        'integral-start-said-for-all-time',
        "fact 20.6's start of a design with K_I said for all t >= 0 instead of up to integral_start",
        'analysis/start.py',
        (('    return "for all t >= 0" if until is None else',
          '    return "for all t >= 0" if True else'),),
        ('tests/test_integral.py::test_fact_20_6_the_start_is_certified_until_integral_action_engages',),
    ),
    # What would pass: the bisection over the hardware with the synthesis as its check.
    Mutation(
        'hardware-bracket-wrong-side',
        'the value needed reported on the failing side of the bracket',
        'analysis/hardware.py',
        (('"needed": values[hi], "fails_at": values[lo],', '"needed": values[lo], "fails_at": values[hi],'),),
        ('tests/test_hardware.py::test_the_needed_control_rate_is_the_least_grid_value_passing_and_the_one_below_it_fails',),
    ),
    Mutation(
        'hardware-bisection-halves-swapped',
        'a passing midpoint taken for a failing one (the search keeps the wrong half: a walk, not a bisection)',
        'analysis/hardware.py',
        (('            if check(mid, SCREEN):\n                hi = mid\n            else:\n                lo = mid',
          '            if check(mid, SCREEN):\n                lo = mid\n            else:\n'
          '                hi = mid'),),
        ('tests/test_hardware.py::test_the_search_is_a_bisection_log2_reduced_checks_and_three_at_the_full_size',),
    ),
    Mutation(
        'hardware-needed-not-confirmed-at-full-size',
        'the value found reported without the full-size synthesis (the reduced check taken for it)',
        'analysis/hardware.py',
        (('        entry = checks.at(case, name, values[i], level, budgets[level], bound)',
          '        entry = checks.at(case, name, values[i], SCREEN, budgets[SCREEN], bound)'),),
        ('tests/test_hardware.py::test_a_value_that_fails_at_the_full_size_is_not_reported_needed_the_bisection_continues_above',),
    ),
    Mutation(
        'hardware-full-size-failure-reported-needed',
        'a value that fails at the full size still reported as needed',
        'analysis/hardware.py',
        (('        if not check(hi, FULL):  # fails at the full size: look above it',
          '        if False:  # fails at the full size: look above it'),),
        ('tests/test_hardware.py::test_a_value_that_fails_at_the_full_size_is_not_reported_needed_the_bisection_continues_above',),
    ),
    Mutation(
        'hardware-lower-end-not-checked-at-full-size',
        "the bracket's failing end taken from the reduced check (a full-size synthesis might pass there)",
        'analysis/hardware.py',
        (('        if lo in full_fail or not check(lo, FULL):\n            break',
          '        if True:\n            break'),),
        ('tests/test_hardware.py::test_where_the_reduced_check_fails_but_the_full_size_passes_the_bisection_goes_down_at_the_full_size',),
    ),
    Mutation(
        'hardware-log-not-reused',
        'a resumed search makes the logged evaluations again',
        'analysis/hardware.py',
        (('for e in ([] if log is None else read_log(log)) if "holds" in e}',
          'for e in [] if "holds" in e}'),),
        ('tests/test_hardware.py::test_an_interrupted_search_resumes_with_the_same_answer_and_no_evaluation_made_twice',),
    ),
    Mutation(
        'hardware-jitter-held-in-periods',
        'a new control rate keeps the latency jitter in control periods (shorter in seconds)',
        'analysis/hardware.py',
        (('            imp["latency_jitter"] = round(imp["latency_jitter"] * ratio)\n', ''),),
        ('tests/test_hardware.py::test_a_new_control_rate_holds_in_seconds_what_the_scenario_gives_in_control_periods',),
    ),
    Mutation(
        'hardware-control-grid-ignores-latency',
        'the control-rate grid keeps the output step whole periods but not the latency',
        'analysis/hardware.py',
        (('    for p in [latency] if latency > 0 else []:',
          '    for p in []:'),),
        ('tests/test_hardware.py::test_the_grids_keep_the_latency_and_the_output_step_whole_periods_and_the_camera_exact',),
    ),
    # --- typed results: one stop record, statuses from their producers -------------------------------------
    Mutation(
        'sil-stop-said-out-of-view',
        'the program-in-the-loop run calls every lost image out_of_view (a point behind the camera included)',
        'analysis/sil.py',
        (('            stop = stop if lost is None else lost\n',
          '            stop = stop if lost is None else Stop(RunStatus.OUT_OF_VIEW, lost.message)\n'),),
        ('tests/test_sil.py::test_a_point_behind_the_camera_stops_both_loops_with_the_same_stop',),
    ),
    Mutation(
        'absent-key-written',
        'a key a result does not have is written (null) in its JSON',
        'analysis/record.py',
        (('                if not f.metadata.get("internal") and getattr(value, f.name) is not ABSENT}',
          '                if not f.metadata.get("internal")}'),),
        ('tests/test_records.py::test_an_absent_key_is_left_out_and_none_is_kept',
         'tests/test_golden.py::test_each_commands_json_is_the_recorded_one[certify]'),
    ),
    Mutation(
        'synthesis-uncertified-speed-passes',
        'a target-speed synthesis whose written design has no certified speed says ok (exit 0)',
        'analysis/synthesize.py',
        (('                outcome = Outcome.UNCERTIFIED\n', '                pass\n'),),
        ('tests/test_synthesize.py::test_a_written_design_without_a_certified_target_speed_is_uncertified',),
    ),
    # --- claims, checks and designs that say no more than they measured ---
    Mutation(
        'check-torque-relative-to-peak',
        'export --check measures each torque difference relative to the run\'s peak torque, not to that torque',
        'analysis/export.py',
        (('        scale = np.maximum(np.abs(reference.tau), np.finfo(float).tiny)\n',
          '        scale = np.maximum(np.abs(reference.tau).max(), np.finfo(float).tiny)\n'),),
        ('tests/test_export.py::test_each_torque_is_compared_relative_to_itself',),
    ),
    Mutation(
        'check-early-stop-counted-zero',
        'export --check counts a closed loop that stopped early as no difference (0) from the Python step\'s',
        'analysis/export.py',
        (('if same_length else float("inf")', 'if same_length else 0.0'),),
        ('tests/test_export.py::test_the_closed_loop_is_the_same_only_when_both_runs_complete_alike',),
    ),
    Mutation(
        'program-statement-on-replay-alone',
        'page 1\'s "the exported program is the simulated controller" passes on the torque replay alone',
        'analysis/results.py',
        (('    status = StatementStatus.PASS if check["passed"] else StatementStatus.FAIL\n',
          '    status = StatementStatus.PASS if check["max_rel_torque_difference"] <= tolerance["torque_relative"] '
          'else StatementStatus.FAIL\n'),),
        ('tests/test_report_text.py::test_the_programs_statement_needs_both_the_replay_and_the_closed_loop',),
    ),
    Mutation(
        'check-passes-on-replay-alone',
        'export --check passes when the torques agree, whatever the loop the compiled step closes',
        'analysis/export.py',
        (('        return (self.max_rel_torque_difference <= TORQUE_TOLERANCE\n'
          '                and self.closed_loop_max_state_difference <= CLOSED_LOOP_TOLERANCE)  # fmt: skip\n',
          '        return self.max_rel_torque_difference <= TORQUE_TOLERANCE\n'),),
        ('tests/test_report_text.py::test_the_programs_statement_needs_both_the_replay_and_the_closed_loop',
         'tests/test_export.py::test_the_closed_loop_is_the_same_only_when_both_runs_complete_alike'),
    ),
    Mutation(
        'stopped-run-claim-passes',
        'verify gives PASS to a claim measured on a run that stopped out of view, diverged or singular '
        '(INCONCLUSIVE only when it ran out of time or the integrator failed)',
        'analysis/verify.py',
        (('    if traj.status is not RunStatus.OK:\n',
          '    if traj.status in (RunStatus.TIME_BUDGET, RunStatus.INTEGRATOR_FAILURE):\n'),),
        ('tests/test_verify.py::test_a_claim_holding_on_a_run_that_stopped_early_is_inconclusive_and_so_is_the_verdict',),
    ),
    Mutation(
        'verdict-ignores-inconclusive',
        'the verdict says every check passes with a check INCONCLUSIVE',
        'analysis/results.py',
        (('    if inconclusive:\n', '    if False:\n'),),
        ('tests/test_verify.py::test_a_claim_holding_on_a_run_that_stopped_early_is_inconclusive_and_so_is_the_verdict',),
    ),
    Mutation(
        'synthesis-margin-full-hold-limit',
        'a gain up to its full hold limit is inside the synthesis\' margins (the 0.8 dropped)',
        'analysis/windows.py',
        (('if k > UPPER_FRACTION * up]', 'if k > up]'),
         ('            if self.held > UPPER_FRACTION * (2 - self.margin) and not found:\n',
          '            if self.held > 2 - self.margin and not found:\n')),
        ('tests/test_synthesize.py::test_a_design_is_inside_the_synthesis_margins_only_with_every_margin_kept',),
    ),
    Mutation(
        'synthesis-margin-joint-unnamed',
        'a gain above 0.8 of its hold limit is said only of the gains together, the joint not named',
        'analysis/windows.py',
        (('if k > UPPER_FRACTION * up]', 'if k > up]'),),
        ('tests/test_synthesize.py::test_a_design_is_inside_the_synthesis_margins_only_with_every_margin_kept',),
    ),
    Mutation(
        'synthesis-margin-lower-end',
        'a gain just above its window\'s lower end is inside the synthesis\' margins (the 1.1 dropped)',
        'analysis/windows.py',
        (('if k < LOWER_FACTOR * low]', 'if k < low]'),),
        ('tests/test_synthesize.py::test_a_design_is_inside_the_synthesis_margins_only_with_every_margin_kept',),
    ),
    Mutation(
        'synthesis-margin-rho-below-one',
        'a design with 0.99 < rho < 1 is inside the synthesis\' margins (fact 14 without its margin)',
        'analysis/synthesize.py',
        (('if implemented["rho"] > RHO_MAX:', 'if implemented["rho"] >= 1:'),),
        ('tests/test_synthesize.py::test_a_design_is_inside_the_synthesis_margins_only_with_every_margin_kept',),
    ),
    Mutation(
        'synthesis-runs-scenario-integral-gain',
        'the synthesis runs a design with K_I = k_i_factor times the scenario\'s K_xi, not the design\'s',
        'analysis/synthesize.py',
        (('integral_gain(case.scenario.gains, point.k_xi)', 'integral_gain(case.scenario.gains, case.point.k_xi)'),),
        ('tests/test_synthesize.py::test_the_synthesis_runs_each_design_with_its_own_integral_gain',),
    ),
    # --- the start's statements ---
    Mutation(
        "ramp-level-without-limit",
        "fact 16a.3's level the recursion's largest bound, without the last step's limit b/k",
        "analysis/start.py",
        (("    level = float(max(*bound, b[j] / k[j]))\n", "    level = float(max(*bound))\n"),),
        ("tests/test_start_levels.py::test_ramp_level_covers_the_limit_its_recursion_rises_to",),
    ),
    Mutation(
        "integral-start-visible-after-t-i",
        "fact 20.6's start keeps the ramp's visibility time past integral_start (certified from after T_I)",
        "analysis/start.py",
        (('    if (record.get("visible_from_s") or 0.0) > t_i:',
          '    if (record.get("visible_from_s") or 0.0) > math.inf:'),),
        ("tests/test_start.py::test_every_time_a_start_statement_names_lies_before_integral_action_engages",),
    ),
    Mutation(
        'self-motion-residual-tenfold',
        'fact 14 on a redundant arm accepts a self-motion tangent residual up to 10 times its tolerance on Pi',
        'analysis/multirate.py',
        (('return check.certified and self.residual < check.tolerance',
          'return check.certified and self.residual < 10 * check.tolerance'),),
        ('tests/test_multirate.py::test_the_self_motion_is_fixed_only_within_the_lyapunov_checks_tolerance',),
    ),
    Mutation(
        "start-statement-without-plant",
        "a start statement computed for the plant without friction does not say so (its sentence, the START line)",
        "analysis/start.py",
        (("        return said_for(self.plant, told)\n", "        return told\n"),),
        ("tests/test_start.py::test_the_start_computed_without_friction_says_so_wherever_it_is_printed",),
    ),
    Mutation(
        "start-row-without-plant",
        "the statements row of a start names its loop and times but not the plant it is computed for",
        "analysis/start.py",
        (('        plant = [] if self.plant is None else [f"for {self.plant}"]\n', "        plant: list[str] = []\n"),),
        ("tests/test_start.py::test_the_start_computed_without_friction_says_so_wherever_it_is_printed",),
    ),
    Mutation(
        "start-plant-not-recorded",
        "the envelope of a plant with friction says its plant, its start record not",
        "analysis/results.py",
        (('        record["start"] = for_plant(record["start"], WITHOUT_FRICTION)\n', ""),),
        ("tests/test_start.py::test_the_start_computed_without_friction_says_so_wherever_it_is_printed",),
    ),
    # --- behaviours guarded by their contract, not by a golden file ---
    Mutation(
        "campaign-latency-truncated",
        "a campaign's drawn latency truncated to the whole control period below, not rounded to the nearest",
        "analysis/dispersion.py",
        (("                value = round(value * imp.control_rate) / imp.control_rate\n",
          "                value = int(value * imp.control_rate) / imp.control_rate\n"),),
        ("tests/test_contract_latency.py::test_a_drawn_latency_rounds_to_the_nearest_control_period",
         "tests/test_contract_latency.py::test_a_drawn_latency_that_is_a_whole_number_of_periods_is_kept"),
    ),
    Mutation(
        "tolerance-bound-reads-stopped-runs",
        "the campaign's tolerance bound reads a stopped run's partial tracking error, not an infinite one",
        "analysis/campaign.py",
        (('            values = np.where(np.asarray(data["status"]) == "ok", np.asarray(data[name], dtype=float), '
          'math.inf)\n',
          "            values = np.asarray(data[name], dtype=float)\n"),),
        ("tests/test_contract_stopped_runs.py::test_a_stopped_run_counts_as_an_infinite_tracking_error_at_every_quantile",
         "tests/test_contract_stopped_runs.py::test_the_bound_does_not_depend_on_the_error_a_stopped_run_reached"),
    ),
    Mutation(
        "auto-substeps-relative-to-state-size",
        'substeps = "auto" judges the step-doubling difference relative to the state\'s size, not its change '
        "over the period",
        "analysis/sampled.py",
        (("    gap, change = np.abs(a - b).max(), np.abs(b - s).max()\n",
          "    gap, change = np.abs(a - b).max(), np.abs(b).max()\n"),),
        ("tests/test_contract_substeps.py::test_the_step_error_estimate_is_the_doubling_difference_over_the_states_change",
         "tests/test_contract_substeps.py::test_auto_asks_for_the_steps_the_states_change_requires_not_its_size"),
    ),
    Mutation(
        "zeroed-inertial-carries-mass",
        "a moved URDF link whose <inertial> gives zero mass and inertia counts as carrying mass (M(q) singular)",
        "models/robot.py",
        (("            if any(float(v) > 0 for v in values):\n", "            if values:\n"),),
        ("tests/test_contract_massless_link.py::test_a_moved_link_without_mass_or_inertia_is_refused_naming_it",),
    ),
    Mutation(
        "campaign-drawn-start-restarts-observer",
        'a campaign run with a drawn q0 or qd0 starts its observer from the [observer] error, not from the first '
        'image as the scenario\'s start does ([start] observer = "image")',
        "analysis/dispersion.py",
        (('        if scenario.start.observer == "image" and not observer:  # gbar(0) from the first image at q0, '
          "as s0's\n",
          "        if False:\n"),),
        ("tests/test_contract_dispersion.py::test_a_drawn_start_changes_the_runs_initial_state_only",
         "tests/test_contract_dispersion.py::test_drawing_the_scenarios_own_values_gives_the_scenarios_run"),
    ),
    Mutation(
        "campaign-worst-ignores-outcome",
        "the campaign's worst runs ranked by closeness alone: a failure closer to holding than a holding run "
        "is not listed first",
        "analysis/campaign.py",
        (('    order = np.lexsort((np.asarray(data["run"]), -closeness, holds))',
          '    order = np.lexsort((np.asarray(data["run"]), -closeness))'),),
        ("tests/test_contract_campaign_summary.py::test_the_worst_runs_are_the_failures_first_then_the_closest_to_failing",),
    ),
    Mutation(
        "integral-rate-not-rechecked",
        "fact 23's rate taken at multipliers the literal matrices do not certify (the a posteriori re-check skipped)",
        "analysis/integral_envelope.py",
        (("        if kappa <= 0 or margin < 0:\n            return\n", "        if False:\n            return\n"),),
        ("tests/test_integral_envelope.py::test_multipliers_the_literal_matrices_do_not_certify_give_no_rate",),
    ),
    Mutation(
        "integral-level-below-the-start",
        "fact 23's level lowered to c_inf without the start's bound on V_eps(T_I) = V(T_I) (the chained start dropped)",
        "analysis/integral_envelope.py",
        (("            c = max(start_level, rate.c_inf) * (1 + 1e-6)\n", "            c = rate.c_inf * (1 + 1e-6)\n"),),
        ("tests/test_integral_envelope.py::test_a_start_above_c_inf_raises_the_level_to_it_and_one_above_c_max_raises_theta_bar",),
    ),
    Mutation(
        "integral-literal-matrix-loses-a-term",
        "fact 23's literal F0 without eps D (the bound of eps xi^T M xi) in each joint's xi entry: looser than the SDP",
        "analysis/integral_envelope.py",
        (("    a0 = k_xi - m.s_t - eps * d - coriolis\n", "    a0 = k_xi - m.s_t - coriolis\n"),),
        ("tests/test_integral_envelope.py::test_at_the_programs_optimum_every_block_of_the_literal_matrices_limits_the_rate",),
    ),
)


def tracked_files() -> list[str]:
    """The repository's files as the working tree has them (tracked and new, not ignored)."""
    out = subprocess.run(["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"], cwd=ROOT,
                         capture_output=True, check=True).stdout  # fmt: skip
    return [f for f in out.decode().split("\0") if f and (ROOT / f).is_file()]


def copy_repository(target: Path) -> None:
    """The tracked files, and the package ``dvfc`` laid out as installed (its sub-packages linked)."""
    for name in tracked_files():
        (target / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(ROOT / name, target / name)
    for layer in LAYERS:
        (target / "dvfc" / layer).symlink_to(Path("..") / layer, target_is_directory=True)


def apply(mutation: Mutation, copy: Path) -> None:
    """Apply the substitutions; a pattern found other than ``count`` times is a harness error."""
    path = copy / mutation.path
    text = path.read_text()
    for old, new in mutation.substitutions:
        found = text.count(old)
        if found != mutation.count:
            raise SystemExit(f"mutation {mutation.name}: pattern found {found} times in {mutation.path}, "
                             f"expected {mutation.count}: {old!r}")  # fmt: skip
        text = text.replace(old, new)
    path.write_text(text)


def pytest(copy: Path, tests: tuple[str, ...]) -> tuple[int, str, float]:
    """Run pytest on the copy (its own modules first on the path); exit status, output, seconds."""
    env = {**os.environ, "PYTHONPATH": str(copy), "PYTHONDONTWRITEBYTECODE": "1"}
    start = time.perf_counter()
    run = subprocess.run([sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider", *tests], cwd=copy,
                         env=env, capture_output=True, text=True)  # fmt: skip
    return run.returncode, run.stdout + run.stderr, time.perf_counter() - start


def check_imports(copy: Path) -> None:
    env = {**os.environ, "PYTHONPATH": str(copy)}
    code = "import dvfc.analysis, dvfc.models; print(dvfc.analysis.__file__, dvfc.models.__file__)"
    out = subprocess.run([sys.executable, "-c", code],
                         cwd=copy, env=env, capture_output=True, text=True, check=True).stdout  # fmt: skip
    if not all(Path(p).resolve().is_relative_to(copy.resolve()) for p in out.split()):  # links resolved
        raise SystemExit(f"the copy's modules are not the ones imported: {out}")


def failing_test(output: str) -> str:
    found = re.findall(r"^FAILED (\S+?(?:\[[^\]]*\])?)(?: - |$)", output, flags=re.MULTILINE)
    return found[0] if found else "?"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", action="append", help="run only the named mutation(s)")
    parser.add_argument("--write", action="store_true", help="rewrite the result table in MUTATIONS.md")
    args = parser.parse_args()
    chosen = [m for m in MUTATIONS if not args.only or m.name in args.only]
    if args.only and len(chosen) != len(args.only):
        raise SystemExit(f"unknown mutation among {args.only}")
    rows, survived, start = [], [], time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="dvfc-mutate-") as tmp:
        pristine = Path(tmp) / "pristine"
        pristine.mkdir()
        copy_repository(pristine)
        check_imports(pristine)
        baseline = sorted({t for m in chosen for t in m.tests})
        code, output, seconds = pytest(pristine, tuple(baseline))
        if code != 0:
            print(output[-3000:])
            raise SystemExit(f"the unmutated code fails its tests (exit {code}): fix that first")
        print(f"baseline: {len(baseline)} test selections pass ({seconds:.0f} s)", flush=True)
        for m in chosen:
            copy = Path(tmp) / m.name
            shutil.copytree(pristine, copy, symlinks=True)
            apply(m, copy)
            code, output, seconds = pytest(copy, m.tests)
            shutil.rmtree(copy)
            if code == 1:
                status, by = "caught", failing_test(output)
            elif code == 0:
                status, by = "SURVIVED", "-"
                survived.append(m.name)
            else:
                print(output[-3000:])
                raise SystemExit(f"mutation {m.name}: pytest exit {code} (not a test failure): harness error")
            rows.append((m, status, by, seconds))
            print(f"{status:8s} {m.name:32s} {seconds:6.1f} s  {by}", flush=True)
    total = time.perf_counter() - start
    print(f"{len(rows) - len(survived)}/{len(rows)} caught in {total:.0f} s")
    if args.write:
        write_table(rows, total)
    return 1 if survived else 0


def write_table(rows, total: float) -> None:
    path = TABLE
    marker = "<!-- results -->"
    head = path.read_text().split(marker)[0] if path.exists() else ""
    lines = [marker, "", f"Last run: {len(rows)} mutations, {total:.0f} s in all.", "",
             "| mutation | file | what | result | caught by | seconds |", "|---|---|---|---|---|---|"]  # fmt: skip
    for m, status, by, seconds in rows:
        what = m.what.replace("|", "\\|")  # a table cell
        lines.append(f"| `{m.name}` | `{m.path}` | {what} | {status} | `{by}` | {seconds:.0f} |")
    path.write_text(head + "\n".join(lines) + "\n")


if __name__ == "__main__":
    sys.exit(main())
