"""The human output of each job's typed result (:mod:`dvfc.analysis.jobs`): tables and sentences on
standard output, read from the result's fields."""

from __future__ import annotations

import numpy as np
from rich.table import Table
from rich.text import Text

from dvfc.analysis.campaign import CampaignResult
from dvfc.analysis.certify import INTEGRAL_COVERAGE
from dvfc.analysis.console import out
from dvfc.analysis.export import ExportResult
from dvfc.analysis.hardware import value_text
from dvfc.analysis.implementation import SubstepChoice
from dvfc.analysis.jobs import CampaignDesignResult
from dvfc.analysis.margins import MarginsResult, linear_margin_text
from dvfc.analysis.multirate import implemented_text
from dvfc.analysis.record import ABSENT
from dvfc.analysis.results import (
    CertificateResult,
    PoseResult,
    SimulationResult,
    VerificationResult,
    channels_text,
)
from dvfc.analysis.synthesize import SynthesisResult
from dvfc.analysis.verify import ClaimStatus


def show_simulation(result: SimulationResult) -> None:
    """A short human summary of a simulation."""
    s = result.summary
    table = Table(title=f"{result.scenario} ({result.mode} e_e)", show_header=False)
    f = s["final"]
    r = s["identity_residuals"]
    at = f" (at {s['final_at']:.4g} s, the last sample before the stop)" if s["stopped"] else ""
    rows = [
        ("status", s["status"]),
        ("horizon", f"{s['t_final']:.3g} s in {s['wall_time']:.3g} s wall"
         + (f", stopped at {s['stopped_at']:.4g} s" if s["stopped"] else "")),
        (f"final{at} tracking error g_d^-1 g: position, angle", f"{f['tracking_position']:.3e} m, "
         + ("-" if f["tracking_angle_deg"] is None else f"{f['tracking_angle_deg']:.3g} deg")),
        ("final control error e_c (estimate vs g_d): |p_ec|, |e_R(R_ec)|",
         f"{f['e_c_position']:.3e} m, {_number(f['e_c_rotation'])}"),
        ("final estimation error e_e (g vs estimate): |p_ee|, |e_R(R_ee)|",
         f"{f['e_e_position']:.3e} m, {_number(f['e_e_rotation'])}"),
        ("V(0) -> V(T)", f"{s['V0']:.4g} -> {s['VT']:.4g}"),
        ("max |tau| applied", f"{s['max_torque']:.4g} N m"),
        ("peak |tau| / effort limit", _worst(result.limits["torque_commanded_ratio"])),
        ("peak |qd| / velocity limit", _worst(result.limits["speed_ratio"])),
        ("joint range / position limits", _worst(result.limits["position_ratio"])),
        ("Lemma 2 identity residual", f"{r['passivity']:.2e}"),
        ("(43) identity residual", f"{r['dissipation']:.2e}"),
        ("max |e_e(image) - e_e|", f"{s['image_estimate_gap_max']:.3e}"),
        *([] if (how := result.integration) is None else [("integration", SubstepChoice.from_dict(how).text)]),
    ]
    if isinstance(row := result.campaign_row, dict):
        verdict = f"{'holds' if row['holds'] else 'FAILS'} ({row['reason']})"
        rows.insert(1, ("campaign run, by the margins criterion", verdict))
    for name, value in rows:
        table.add_row(name, str(value))
    out.print(table)
    out.print(f"trajectory: {result.outputs['trajectory']}\nsummary:    {result.outputs['summary']}")


def show_solution(solution: dict) -> None:
    """The configuration of ``pose --solve``: the line to paste, then its conditioning and errors."""
    limits = "every joint within its position limits" if solution["within_position_limits"] else (
        "joint(s) " + ", ".join(str(j + 1) for j, ok in enumerate(solution["joints_within_limits"]) if not ok)
        + " OUTSIDE their position limits")  # fmt: skip
    out.print(solution["q0_toml"], markup=False, soft_wrap=True)
    out.print(f"sigma_min(J_b) = {solution['sigma_min_body_jacobian']:.4g}, condition number "
              f"{solution['condition_number']:.4g}; pose error {solution['position_error_m']:.2e} m, "
              f"{solution['rotation_error_rad']:.2e} rad; {limits}", markup=False, soft_wrap=True)  # fmt: skip


def show_pose(result: PoseResult) -> None:
    """Human output of ``pose``."""
    if (solution := result.solution) is not None:
        show_solution(solution)
    vec = lambda v: "[" + ", ".join(f"{x:.4g}" for x in v) + "]"  # noqa: E731
    for label, key in (("camera g_wc(q0)", "camera_in_world"), ("target g_wo(0)", "target_in_world"),
                       ("target from the camera g(0)", "target_in_camera")):  # fmt: skip
        pose_ = getattr(result, key)
        out.print(f"{label}: xyz = {vec(pose_['xyz'])} m, rpy = {vec(pose_['rpy'])} rad", markup=False, soft_wrap=True)
    size = result.image_size
    table = Table(title=f"feature points ({result.image_coordinates}"
                  + (f", image {size[0]:g} x {size[1]:g})" if size else ")"))  # fmt: skip
    for col in ("point", "u [px]", "v [px]", "depth [m]", "in view"):
        table.add_column(Text(col))
    for f in result.features:
        table.add_row(str(f["point"]), f"{f['image'][0]:.1f}", f"{f['image'][1]:.1f}", f"{f['depth']:.4g}",
                      "yes" if f["in_view"] else "NO")  # fmt: skip
    out.print(table)
    if (windows := result.gain_windows) is not None:
        show_windows(windows)
    cost = result.integration
    out.print(f"integration: {cost['integrator']['text']}; about {cost['wall_time_per_run']:.3g} s a "
              f"{cost['duration']:g} s run ({cost['basis']})", markup=False, soft_wrap=True)  # fmt: skip


def show_windows(windows: dict) -> None:
    """The gain windows of ``pose``: per joint ``k_xi``, the window and whether it lies inside."""
    table = Table(title="gain windows of k_xi (lower: " + windows["lower"] + "; upper: "
                  + (windows["upper"] or "none, the ideal continuous loop has no hold") + ")")  # fmt: skip
    for col in ("joint", "k_xi", "lower", "upper", "inside"):
        table.add_column(Text(col))
    for i, (k, (lo, hi), inside) in enumerate(zip(windows["k_xi"], windows["windows"], windows["inside"], strict=True)):
        upper = "-" if hi is None else f"{hi:.4g}" + (" (alone)" if windows["upper_alone"][i] else "")
        table.add_row(str(i + 1), f"{k:.4g}", f"{lo:.4g}", upper, "yes" if inside else "NO")
    out.print(table)


def _worst(ratios: list[float]) -> str:
    """The largest of per-joint ratios to a limit, with its joint and a plain verdict."""
    j = int(np.argmax(ratios))
    verdict = "within the URDF limit" if ratios[j] <= 1 else "EXCEEDS the URDF limit"
    return f"{ratios[j]:.3g} (joint {j + 1}, {verdict})"


def _number(value: float | None) -> str:
    return "-" if value is None else f"{value:.3e}"


def show_certificate(result: CertificateResult) -> None:
    """Human output of ``certify``: the point, the region, the method and a verdict."""
    p = result.points[0]
    table = Table(title=f"Theorem 2 certificate: {result.scenario}", show_header=False)
    fmt = lambda v: f"{v:.6g}" if isinstance(v, float | int) else "-"  # noqa: E731
    rows = [
        ("k_xi, k_c, k_e", f"{p.gains['k_xi']}, {p.gains['k_c']}, {p.gains['k_e']}"),
        ("w_pc, w_rc, w_pe, w_re", ", ".join(f"{v:g}" for v in p.weights.values())),
        ("region", result.region),
        ("method", p.method),
        ("gamma (certified)", fmt(p.gamma)),
        ("margin lambda_min(P)", fmt(p.margin)),
        ("gamma_tight (alpha V, fact 4)", f"{fmt(p.gamma_tight)} (alpha = {fmt(p.alpha)})"),
        ("gamma_lower: linearisation, nonlinear from rest",
         f"{fmt(p.gamma_lower_linear)}, {fmt(p.gamma_lower_nonlinear)}"),
        ("tightness gamma / gamma_lower", fmt(p.tightness)),
        ("worst gamma found by search", fmt(p.gamma_worst_found)),
    ]
    for name, value in rows:
        table.add_row(name, str(value))
    out.print(table)
    if p.certified:
        channels = channels_text(p.to_json(), result.loop == "planar")
        out.print(f"CERTIFIED: L2 gain <= {fmt(p.gamma)} {channels} over {result.region}.", markup=False)
    else:
        out.print(f"NOT CERTIFIED: {p.reason}", markup=False)
    if isinstance(integral := p.integral, dict):  # docs/math.md, facts 20-21
        covered = "; ".join(f"{key.replace('_', ' ')}: {integral[key]}" for key in INTEGRAL_COVERAGE)
        out.print(f"WITH INTEGRAL ACTION (k_i = {integral['k_i']}): {covered}.", markup=False)
    if isinstance(p.implemented, dict):
        out.print(implemented_text(p.implemented), markup=False, soft_wrap=True)
    if isinstance(p.envelope, dict):
        show_envelope(p.envelope)


def inertia_text(e: dict) -> str:
    """The diagonal of the envelope's ``D_M`` (docs/math.md, fact 10), 4 significant figures."""
    return ", ".join(f"{row[i]:.4g}" for i, row in enumerate(e["inertia"]["upper"]))


def show_envelope(e: dict) -> None:
    """Human output of the operating envelope (docs/math.md, facts 7-9)."""
    if e.get("rate") is None:
        out.print(f"Operating envelope: not certified: {e['reason']}", markup=False)
        if (start := e.get("start") or {}).get("until_s") is not None:  # docs/math.md, fact 20.6
            told = f"CERTIFIED: {start['statement']}" if start["inside"] else f"not certified: {start.get('reason')}"
            out.print(f"START (until integral action engages): {told}", markup=False)
        if e.get("friction") is not None:
            out.print(f"ENVELOPE: {e['friction']['statement']}.", markup=False)
        return
    fmt = lambda v, unit="": "-" if v is None else f"{v:.4g}{unit}"  # noqa: E731
    d, b, start = e["disturbance"], e["bounds"], e["start"]
    table = Table(title="Operating envelope (facts 7-9)", show_header=False)
    rows = [
        ("disturbance bounds", f"speed {fmt(d['target_speed'], ' m/s')}, rate {fmt(d['target_rate'], ' rad/s')}, "
                               f"|tau_d| {fmt(d['torque'], ' N m')} (wbar = {fmt(e['wbar'])})"),
        ("decay rate kappa", f"{fmt(e['rate'], ' 1/s')} (gamma' = {fmt(e['gamma_prime'])}, "
                             f"theta_bar = {fmt(e['theta_bar_deg'], ' deg')})"),
        ("inertia (from the URDF, every q)", f"m_lo I <= M(q) <= D_M = diag({inertia_text(e)}) kg m^2 "
                                             f"(lambda_max(B) = {fmt(e['m_hi'])}; fact 10)"),
        ("ultimate V (c_inf)", fmt(e["ultimate_V"])),
        ("ultimate |p_ec|, theta_ec", f"{fmt(b['p_ec'], ' m')}, {fmt(b['theta_ec_deg'], ' deg')}"),
        ("ultimate |p_ee|, theta_ee", f"{fmt(b['p_ee'], ' m')}, {fmt(b['theta_ee_deg'], ' deg')}"),
        ("ultimate |xi|", fmt(b["xi"], " rad/s")),
        ("start V(0) (kinetic part)", f"{fmt(start['V0'])} ({fmt(start.get('kinetic'))}): "
                                      f"{'inside' if start['inside'] else 'NOT inside'} the certified set "
                                      f"(reference {start.get('method', 'constant')})"),
        ("visible, margin to border, min depth", f"{e['visible']}, {fmt(e['image_margin_px'], ' px')}, "
                                                  f"{fmt(e['depth_min'], ' m')}"),
        ("largest target speed with every statement certified (features in view)", fmt(e["max_target_speed"], " m/s")),
        ("largest certified |tau_d|", fmt(e["max_torque"], " N m")),
    ]  # fmt: skip
    for name, value in rows:
        table.add_row(name, value)
    out.print(table)
    out.print(f"ENVELOPE: {e['statement']}. Assumes: {'; '.join(e['assumptions'])}.", markup=False)
    if start.get("method") == "planned":
        told = start.get("statement") or f"not certified: {start.get('reason')}"
        out.print(f"START (fact 16b): {told}. Assumes: {'; '.join(start['assumptions'])}.", markup=False)


def show_grid(result: CertificateResult) -> None:
    """Human output of a grid sweep: the named points (each labelled), the region, the count."""
    table = Table(title=f"Theorem 2 over the grid: {result.scenario}")
    for col in ("point", "gamma", "k_xi", "k_c", "k_e", "w_pc, w_rc, w_pe, w_re", "certified"):
        table.add_column(Text(col))
    for p in result.points:
        g = p.gains
        gamma = "-" if p.gamma is None else f"{p.gamma:.6g}"
        weights = ", ".join(f"{v:g}" for v in p.weights.values())
        short = lambda v: Text(", ".join(f"{x:.3g}" for x in v))  # noqa: E731
        table.add_row(Text(str(p.label)), gamma, short(g["k_xi"]), short(g["k_c"]), short(g["k_e"]), weights,
                      str(p.certified))  # fmt: skip
    out.print(table)
    out.print(
        f"region: {result.region}; method: exact closed form (fact 3), blockwise-minimum K_e (fact 5)",
        markup=False,
    )
    stored = result.points_csv or result.points_dataset
    counted = f"{result.summary.certified} of {result.summary.points} points certified"
    out.print(f"{counted}; results: {stored}", markup=False)


def show_synthesis(record: SynthesisResult) -> None:
    """Human output of ``synthesize``: the gains, the certified gamma, the file written, the run
    against the arm's limits (and the limits search: what was searched, what it found)."""
    p = record.point
    if p is None:
        out.print(f"NOT SYNTHESIZED: {record.status}", markup=False, soft_wrap=True)
        _show_limit_search(record)
        return
    g = p.gains
    out.print(
        f"gains: k_xi = {g['k_xi']}\n       k_c = {g['k_c']}\n       k_e = {g['k_e']}\n"
        f"weights: {p.weights}\ncertified gamma = {p.gamma:.6g} over {record.region}\n"
        f"scenario written: {record.scenario_file or 'none, ' + record.status}",
        markup=False,
    )
    if record.max_target_speed is not ABSENT:
        speed = record.max_target_speed
        line = (f"NOT CERTIFIED: {record.status}" if speed is None
                else f"certified max target speed = {speed:.6g} m/s ({p.to_json()['envelope']['statement']})")
        out.print(line, markup=False, soft_wrap=True)
    if isinstance(limits := record.limits, dict):
        out.print(f"run of the design ({limits['status']}): peak |tau| / effort limit "
                  f"{_worst(limits['torque_commanded_ratio'])}, peak |qd| / velocity limit "
                  f"{_worst(limits['speed_ratio'])}", markup=False, soft_wrap=True)  # fmt: skip
    if isinstance(record.implemented, dict):
        out.print(implemented_text(record.implemented), markup=False, soft_wrap=True)
    if isinstance(start := record.start, dict) and start["lost"]:
        out.print(f"START NOT CERTIFIED: {start['statement']}", markup=False, soft_wrap=True)
    _show_limit_search(record)


def _show_limit_search(record: SynthesisResult) -> None:
    """The limits search of ``synthesize`` in words (nothing without ``respect_limits``)."""
    search = record.limit_search
    if not isinstance(search, dict):
        return
    fmt = lambda v: "-" if v is None else f"{v:.3g}"  # noqa: E731
    top = search["trials"][0]
    out.print(
        f"limits search ({search['runs']} runs, {search['syntheses']} syntheses): {search['family']}, alpha in "
        f"[{search['bracket'][0]:.4g}, 1]; criterion: {search['criterion']}.\n{search['statement']}.\n"
        f"unconstrained optimum (alpha = 1): certified gamma {fmt(top['gamma'])}, peak |tau| / effort limit "
        f"{fmt(top['torque_commanded_ratio'])}, peak |qd| / velocity limit {fmt(top['speed_ratio'])} "
        f"({top['status']}{'; ' + top['sampled'] if top.get('sampled') else ''})",
        markup=False,
        soft_wrap=True,
    )


def show_verification(result: VerificationResult) -> None:
    """Human output of ``verify``: a table of the claims (each with its place in the paper, its
    status, value and bound) narrow enough for 80 columns, each FAIL or INCONCLUSIVE reason in
    full below it, then a verdict."""
    claims = result.claims
    table = Table(title=f"Claims of the paper on {result.scenario}")
    table.add_column("claim", ratio=1, overflow="fold")
    table.add_column("status", no_wrap=True, min_width=len("INCONCLUSIVE"))
    table.add_column("value", no_wrap=True)
    table.add_column("bound", max_width=24, overflow="fold")
    colours = {ClaimStatus.PASS: "green", ClaimStatus.FAIL: "red", ClaimStatus.INCONCLUSIVE: "yellow",
               ClaimStatus.MEASURED: "default"}  # fmt: skip
    for c in claims:
        table.add_row(Text(f"{c.name} ({c.reference})"), Text(c.status, style=colours[c.status]), f"{c.value:.3e}",
                      Text(c.bound))  # fmt: skip
    out.print(table)
    for c in claims:
        if c.status in (ClaimStatus.FAIL, ClaimStatus.INCONCLUSIVE):
            out.print(Text(f"{c.status} {c.name}: {c.detail}", style=colours[c.status]))
    summary_ = result.summary
    problems = [f"{summary_.failed} claim(s) FAIL"] if summary_.failed else []
    problems += [f"{summary_.inconclusive} check(s) INCONCLUSIVE"] if summary_.inconclusive else []
    verdict = "; ".join(problems) or "every claim holds"
    out.print(f"{verdict} ({summary_.claims} checked)", markup=False)


def show_margins(result: MarginsResult) -> None:
    """Human output of ``margins``: each parameter's breaking point, measured, the horizon its last
    holding run was judged on, and the margin against fact 14's linear one; or what would pass."""
    if result.margins is None:
        if isinstance(result.what_would_pass, dict):
            show_what_would_pass(result.what_would_pass)
        return
    table = Table(title=f"Margins of the loop as implemented: {result.scenario} (measured)")
    for col in ("parameter", "margin", "holds at", "breaks at", "range", "horizon, growth", "fact 14", "note"):
        table.add_column(col)
    fmt = lambda v: "-" if v is None else f"{v:.4g}"  # noqa: E731
    for name, m in result.margins.items():
        value = f"{fmt(m['value'])} {m['unit']}"
        if m["value"] is None and m["holds_at"] is not None:
            value = f"holds throughout (to {fmt(m['holds_at'])} {m['unit']})"
        span = "-" if m.get("range") is None else f"{fmt(m['range'][0])} .. {fmt(m['range'][1])}"
        horizon = horizon_text(m.get("holds_run"))
        note = m.get("breaks_because") or m.get("reason") or ""
        table.add_row(name, value, fmt(m["holds_at"]), fmt(m["breaks_at"]), span, horizon, linear_text(m), note)
    out.print(table)
    for name, m in result.margins.items():
        if m.get("linear", {}).get("clipped"):
            out.print(f"{name}: {m['linear']['statement']}", markup=False, soft_wrap=True)
    out.print(f"criterion: {result.criterion}", markup=False, soft_wrap=True)
    own = result.scenario_run
    assert isinstance(own, dict)
    out.print(f"the scenario's own run ({horizon_text(own)}): {own['detail']}", markup=False, soft_wrap=True)
    out.print(linear_margin_text(result.to_json()), markup=False, soft_wrap=True)
    if isinstance(result.what_would_pass, dict):
        show_what_would_pass(result.what_would_pass)


def linear_text(margin: dict) -> str:
    """A measured margin against fact 14's linear one, in a few words (``linear.statement`` in full)."""
    linear = margin.get("linear")
    if linear is None:
        return "-"
    if not linear["checked"]:
        return "measured only"
    if linear["linear_margin"] is None:
        return "stable over its range"
    return f"{'clipped to' if linear['clipped'] else 'within'} {linear['linear_margin']:.4g} {margin['unit']}"


def horizon_text(run: dict | None) -> str:
    """A run's horizon and growth check in words (``-`` for none)."""
    if run is None:
        return "-"
    growth = run["growth"]
    if growth is None:
        return f"{run['horizon']:.4g} s"
    return f"{run['horizon']:.4g} s, envelope x{growth['ratio']:.3g} ({'growing' if growth['growing'] else 'steady'})"


def show_what_would_pass(found: dict) -> None:
    """Human output of ``--what-would-pass``: per parameter today's value, the value needed, the bracket
    the bisection ended on and the full-size confirmation; how it was measured."""
    today = found["today"]
    if today["holds"]:
        out.print("what would pass: nothing to change (the synthesis passes at the scenario's hardware)", markup=False)
        return
    table = Table(title=f"What would pass: {found['scenario']} (measured)")
    columns = ("parameter", "today", "needed", "bracket (full size)", "confirmation (full size)", "why it fails below")
    for col in columns:
        table.add_column(col)
    for name, p in found["parameters"].items():
        value = lambda v, u=p["unit"]: value_text(v, u)  # noqa: E731
        if p["needed"] is None:
            needed, bracket = "none in range", f"fails at {value(p['fails_at'])}"
        else:
            needed = value(p["needed"])
            bracket = f"fails at {value(p['fails_at'])}, passes at {value(p['passes_at'])}"
        c = p["confirmation"]
        confirmation = "-" if c is None else (f"{c['failures']} of {c['runs']} fail, P(fail) <= "
                                              f"{c['p_fail_upper']:.3g} at {c['confidence']:.0%}")  # fmt: skip
        table.add_row(name, value(p["today"]), needed, bracket, confirmation, p["fails_because"] or "")
    out.print(table)
    out.print(f"as it is: {today['limits']}", markup=False, soft_wrap=True)
    for key in ("method", "held", "assumption"):
        out.print(f"{key}: {found[key]}", markup=False, soft_wrap=True)
    out.print(f"{found['evaluations']} syntheses ({found['made']} made now, {found['evaluations'] - found['made']} "
              f"from the log), {found['seconds']:.0f} s", markup=False, soft_wrap=True)  # fmt: skip


def show_campaign_design(record: CampaignDesignResult) -> None:
    """Human output of ``synthesize --for-campaign``: the design, its checks, the confirmation, the file."""
    if record.scenario_file is None:
        out.print(f"NOT SYNTHESIZED: {record.limits}", markup=False, soft_wrap=True)
        if isinstance(record.what_would_pass, dict):
            show_what_would_pass(record.what_would_pass)
        return
    d, c, s, f = record.design, record.checks, record.search, record.confirmation
    assert d is not None and c is not None and f is not None
    out.print(
        f"gains: k_xi = {d['k_xi']}\n       k_c = {d['k_c']}\n       k_e = {d['k_e']}\n"
        f"       k_i_factor = {d['k_i_factor']:g} (K_I = k_i_factor K_xi)\n"
        f"inside the gain windows; certified gamma = {c['gamma']:.6g}; loop as implemented with the integral state "
        f"(fact 14, local): rho = {c['rho']:.6g} <= {c['rho_max']:g}, Lyapunov margin {c['lyapunov_margin']:.3g}\n"
        f"search: {s['method']}, {s['candidates']} candidates, surrogate {record.surrogate:.4g} ({s['surrogate']})\n"
        f"confirmation: {f['statement']}; largest tracking angle {f['max_tracking_angle_deg']:.3g} deg "
        f"(criterion {record.tracking_bound['angle_deg']:.4g})\n"
        f"scenario written: {record.scenario_file} ({record.seconds:.0f} s)",
        markup=False,
        soft_wrap=True,
    )
    if isinstance(record.what_would_pass, dict):
        show_what_would_pass(record.what_would_pass)


def tolerance_text(tolerance: dict) -> str:
    """The tolerance bound's statement with its values (the order statistic of its rank)."""
    if tolerance["rank"] is None:
        return tolerance["statement"]
    return (f"{tolerance['statement']}: position <= {tolerance['tracking_position']:.4g} m, angle <= "
            f"{tolerance['tracking_angle_deg']:.4g} deg, tracking ratio <= {tolerance['tracking_ratio']:.4g} "
            f"({tolerance['note']})")  # fmt: skip


def show_campaign(result: CampaignResult) -> None:
    """Human output of ``campaign``: the statement, the tolerance bound, the strongest drivers, the worst runs."""
    out.print(result.statement, markup=False, soft_wrap=True)
    out.print(f"criterion: {result.criterion}", markup=False, soft_wrap=True)
    out.print(result.zero_failure["statement"], markup=False, soft_wrap=True)
    unstable = result.local["unstable_runs"]
    out.print(f"local: {result.local['statement']}" + (f"; not certified for runs {unstable}" if unstable else ""),
              markup=False, soft_wrap=True)  # fmt: skip
    out.print(f"tolerance: {tolerance_text(result.tolerance)}", markup=False, soft_wrap=True)
    if result.local_error_q is not None:
        out.print(f"integration: {result.local_error_q['statement']}", markup=False, soft_wrap=True)
    table = Table(title="Drivers of the closeness to failing (PAWN, Spearman; measured)")
    for name in ("quantity", "entry", "PAWN", "above floor", "spearman", "failure rate per quartile"):
        table.add_column(name)
    for e in result.sensitivity:
        rates = " ".join("-" if r is None else f"{r:.2f}" for r in e["failure_rate"])
        above = {True: "yes", False: "no", None: "-"}[e["above_floor"]]
        table.add_row(e["quantity"], e["column"], _number(e["pawn"]), above,
                      _number(e["spearman"]), rates)  # fmt: skip
    out.print(table)
    out.print(f"floor: {result.sensitivity_floor['note']}", markup=False, soft_wrap=True)
    for w in result.worst:
        out.print(f"run {w['run']}: {'holds' if w['holds'] else 'fails'} ({w['reason']}); replay: {w['replay']}",
                  markup=False, soft_wrap=True)  # fmt: skip
    if isinstance(found := result.worst_case_search, dict):
        out.print(f"worst case found ({found['statement']}): closeness to failure {found['worst_closeness']:.4g}; "
                  f"replay: {found['replay']}", markup=False, soft_wrap=True)  # fmt: skip
    if isinstance(result.what_would_pass, dict):
        show_what_would_pass(result.what_would_pass)
    elif result.what_would_pass is None:
        out.print("what would pass: no run fails, nothing to change", markup=False)


def show_export(result: ExportResult) -> None:
    """Human output of ``export``."""
    record = result.to_json()
    out.print(f"exported: {record['api']} ({len(record['files'])} files, state of {record['state_size']} doubles); "
              f"program SHA-256 {record['sha256']}", markup=False, soft_wrap=True)  # fmt: skip
    if (c := record["check"]) is not None:
        out.print(f"check over {c['samples']} samples: largest torque difference {c['max_abs_torque_difference']:.3g} "
                  f"N m, closed loop {c['closed_loop_max_state_difference']:.3g}", markup=False, soft_wrap=True)
    if (t := record["timing"]) is not None:
        c = t["thread_cpu"]
        out.print(f"step time (measured, {t['calls']} calls with an image): median {t['median_us']:.3g} us, "
                  f"p99.9 {t['p999_us']:.3g} us, max {t['max_us']:.3g} us wall; CPU time p99.9 {c['p999_us']:.3g} us, "
                  f"max {c['max_us']:.3g} us", markup=False, soft_wrap=True)
