"""``dvfc report``: the HTML opens in a real browser, the PDF renders, both tell the same gamma."""

from __future__ import annotations

import json
import pickle
import re
import shutil
import signal
import subprocess
import sys
import time
import tomllib
from html import unescape
from pathlib import Path

import matplotlib.image as mpimg
import numpy as np
import pytest
import tomli_w
from typer.testing import CliRunner

import dvfc
from dvfc.analysis.margins import PARAMETERS
from dvfc.analysis.scenario import DEFAULT_SCENARIO
from dvfc.reports.cli import app
from dvfc.reports.stages import CACHE

from helpers import default_dict_without_integral

# The tests marked slow read the whole review of the default scenario (about a minute) or make reports of their own.
EXAMPLES = Path(__file__).parent.parent / "examples"
CHROMIUM = shutil.which("chromium")
POPPLER = shutil.which("pdftoppm")
FIGURES = (
    "fig-map", "fig-envelope", "fig-paths", "fig-image", "fig-errors",
    "fig-storage", "fig-torques", "fig-supply", "fig-l2",
)  # fmt: skip


REPORT_DURATION = 4.0
"""Seconds: past the planned start (2 s) with the start's transient settled, so that every section has its
statement; the margins' runs (the report's costliest stage) are as long."""


@pytest.fixture(scope="module")
def report(tmp_path_factory) -> tuple[Path, Path, str]:
    """The report of the default scenario with the paper's law (without its integral action, so that
    every section has its certificate to show) over :data:`REPORT_DURATION`, made by the installed command line."""
    out = tmp_path_factory.mktemp("report")
    scenario = out / "ur5_circle.toml"
    data = default_dict_without_integral()
    data["simulation"]["duration"] = REPORT_DURATION
    scenario.write_text(tomli_w.dumps(data))
    proc = subprocess.run([sys.executable, "-m", "dvfc.reports", "report", str(scenario), "--out", str(out)],
                          capture_output=True, text=True)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    return out / "report.html", out / "report.pdf", proc.stdout


def section_of(html: str, heading: str) -> str:
    """The report's section from ``heading`` to the next section's heading."""
    start = html.index(heading)
    return html[start : html.index("<h2", start + 1)]


def certified_gamma(html: str) -> str:
    match = re.search(r'<span id="gamma">([^<]+)</span>', html)
    assert match, "the verdict prints no certified gamma"
    return match.group(1)


@pytest.mark.slow
def test_paths_printed(report):
    html, pdf, stdout = report
    assert str(html) in stdout and str(pdf) in stdout


@pytest.mark.slow
def test_gamma_is_the_certificates(report, tmp_path):
    """The gamma in the verdict is the one ``dvfc certify`` certifies for the same scenario."""
    runner = CliRunner()
    target = tmp_path / "c.json"
    runner.invoke(app, ["certify", str(DEFAULT_SCENARIO), "--no-lower-bounds", "--json", str(target)])
    gamma = json.loads(target.read_text())["points"][0]["gamma"]
    assert certified_gamma(report[0].read_text()) == f"{gamma:.6g}"


@pytest.mark.slow
def test_html_self_contained(report):
    """Nothing is fetched: references are in-page anchors or data URIs; no link, no script;
    every figure is inline SVG."""
    html = report[0].read_text()
    assert not re.search(r'\b(src|href)\s*=\s*"(?!#|data:)', html)
    assert "<link" not in html and "<script" not in html and not re.search(r"url\((?!#)", html)
    for figure in FIGURES:
        assert re.search(rf'<figure id="{figure}"><svg', html), figure


@pytest.mark.slow
def test_every_claim_listed(report):
    """The checklist has a row per claim of ``verify`` (16 of the paper, the singularity
    check, the run from rest reaching the lower bound, 3 measurements of the image loop,
    9 of the operating envelope, and the run as implemented: it completes, its torques, joint
    speeds and joint positions are within the URDF's limits, its storage identity (fact 11)
    holds) with a status."""
    html = report[0].read_text()
    rows = re.findall(r'<span class="(PASS|FAIL|INCONCLUSIVE|MEASURED)">', html[html.index('<table id="claims">') :])
    assert len(rows) == 35 and rows.count("MEASURED") == 6 and rows.count("PASS") == 29


@pytest.mark.slow
def test_banner_carries_the_failed_checks(report, tmp_path):
    """The verdict on page 1 is the certificate AND the checks: with one claim failing (its
    stored verification edited), the banner is not green, names the claim with its reason,
    the checklist shows the reason beside the FAIL, and ``report`` exits 1 saying so."""
    out = tmp_path / "out"
    shutil.copytree(report[0].parent, out)
    stored = out / CACHE / "verification.pkl"
    payload = pickle.loads(stored.read_bytes())
    claim = payload["value"]["claims"][0]
    claim.update(status="FAIL", detail="measured 3e-3, required <= 1e-06")
    payload["value"]["summary"]["failed"] = 1
    stored.write_bytes(pickle.dumps(payload))
    result = CliRunner().invoke(app, ["report", str(out / "ur5_circle.toml"), "--out", str(out), "--resume"])
    assert result.exit_code == 1, result.output
    html = (out / "report.html").read_text()
    banner = html[html.index('id="verdict"') : html.index("</div>", html.index('id="verdict"'))]
    assert 'class="verdict fail"' in html and "CERTIFIED, but 1 of" in banner
    assert claim["claim"] in banner and "measured 3e-3" in banner
    row = html[html.index('<table id="claims">') :].split("</tr>")[1]
    assert '<span class="FAIL">FAIL</span><br><span class="small reason">measured 3e-3' in row
    assert f"FAIL {claim['paper']}: {claim['claim']}" in result.stdout


@pytest.mark.slow
def test_lemma_2_caption_holds_for_the_run_shown(report):
    """With a moving target and torque noise (w != 0) int u^T nu falls below -V(0) (so (37),
    stated for w = 0, is not what the run shows); the figure's caption states what holds:
    V(t) - V(0) = int u^T nu + int x^T G w >= -V(0), true on the run to round-off."""
    html = report[0].read_text()
    stored = pickle.loads((report[0].parent / CACHE / "simulation.pkl").read_bytes())["value"]
    supply, v0 = stored.integrals["supply_u_nu"], stored["V"][0, 0]
    total = supply + stored.integrals["supply_x_G_w"]
    assert supply.min() < -v0 and total.min() >= -v0 * (1 + 1e-6)
    caption = html[html.index('<figure id="fig-supply">') :].split("<figcaption>")[1].split("</figcaption>")[0]
    assert "V(t) - V(0) = int u<sup>T</sup>nu + int x<sup>T</sup>G w" in caption
    assert "stated for w = 0" in caption


@pytest.mark.slow
def test_html_renders_in_chromium(report, tmp_path):
    """Headless Chromium loads the page with no console error and no failed request, every
    figure draws at a real size with content, and the screenshot is not blank."""
    assert CHROMIUM, "chromium is missing: make test installs it (system-deps)"
    from playwright.sync_api import sync_playwright

    messages: list[str] = []
    failed: list[str] = []
    args = ["--no-sandbox", "--disable-gpu", "--no-first-run", "--disable-background-networking",
            "--disable-component-update", "--disable-sync"]  # fmt: skip
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=args)
        page = browser.new_page(viewport={"width": 1200, "height": 900})
        page.on("console", lambda m: messages.append(m.text) if m.type in ("error", "warning") else None)
        page.on("pageerror", lambda e: messages.append(str(e)))
        page.on("requestfailed", lambda r: failed.append(r.url))
        page.goto(report[0].as_uri(), wait_until="load")
        sizes = page.evaluate(
            """ids => ids.map(id => {
                const s = document.querySelector('#' + id + ' svg');
                if (!s) return null;
                const r = s.getBoundingClientRect();
                return [r.width, r.height, s.querySelectorAll('path').length];
            })""",
            list(FIGURES),
        )
        broken = page.evaluate("Array.from(document.images).filter(i => !i.complete || i.naturalWidth === 0).length")
        shot = tmp_path / "shot.png"
        page.screenshot(path=str(shot), full_page=True)
        browser.close()
    assert not messages and not failed and broken == 0
    for figure, size in zip(FIGURES, sizes, strict=True):
        assert size is not None and size[0] > 200 and size[1] > 150 and size[2] > 10, (figure, size)
    pixels = mpimg.imread(shot)[..., :3]
    assert pixels.std() > 0.05 and (pixels < 0.5).mean() > 0.005


@pytest.mark.slow
def test_pdf_renders(report, tmp_path):
    """Every page of the PDF rasterises, not blank; the page count is plausible; the text
    holds the certified gamma printed in the HTML."""
    assert POPPLER, "poppler-utils is missing: make test installs it (system-deps)"
    html, pdf, _ = report
    info = subprocess.run(["pdfinfo", str(pdf)], capture_output=True, text=True, check=True).stdout
    pages = int(re.search(r"Pages:\s+(\d+)", info).group(1))
    assert 4 <= pages <= 15
    subprocess.run([POPPLER, "-r", "30", "-png", str(pdf), str(tmp_path / "page")], check=True)
    images = sorted(tmp_path.glob("page-*.png"))
    assert len(images) == pages
    for image in images:
        assert np.asarray(mpimg.imread(image))[..., :3].std() > 0.02, image.name
    text = subprocess.run(["pdftotext", str(pdf), "-"], capture_output=True, text=True, check=True).stdout
    best = re.search(r'<span id="gamma-best">([^<]+)</span>', html.read_text()).group(1)
    assert f"L2 gain ≤ {best}" in " ".join(text.split())


def test_bad_scenario_writes_nothing(tmp_path):
    """Bad input: one line naming the field, status 2, no report file."""
    bad = tmp_path / "bad.toml"
    bad.write_text(DEFAULT_SCENARIO.read_text().replace("focal_length = 800.0", "focal_length = -1.0"))
    result = CliRunner().invoke(app, ["report", str(bad), "--out", str(tmp_path / "out")])
    assert result.exit_code == 2
    assert result.stderr.strip().startswith("error: camera.focal_length")
    assert not (tmp_path / "out" / "report.html").exists() and not (tmp_path / "out" / "report.pdf").exists()


@pytest.mark.slow
def test_grid_scenario_maps_its_first_two_axes(tmp_path):
    """With a [grid], the map is gamma over its first two axes (the others at the design),
    with the certified region outlined: its edge is drawn when some cells are not certified."""
    text = (EXAMPLES / "ur5_grid.toml").read_text()  # edited as text: the axes keep their order
    scenario = tmp_path / "grid.toml"
    scenario.write_text(text.replace("duration = 10.0", "duration = 2.0").replace("jit = true", "jit = false"))
    result = CliRunner().invoke(app, ["report", str(scenario), "--out", str(tmp_path / "out")])
    assert result.exit_code == 0, result.stderr
    html = (tmp_path / "out" / "report.html").read_text()
    figure = html[html.index('<figure id="fig-map">') : html.index("</figure>", html.index('<figure id="fig-map">'))]
    assert "Certified gamma over k_c and k_e (the first two [grid] axes; w_pc at the design" in figure
    assert "edge of the certified region" in figure


@pytest.mark.slow
def test_interrupted_report_resumes(tmp_path):
    """SIGINT while the margins are being measured (after the simulation, certificate and
    verification stages): exit 130 with one line naming --resume; the resumed report redoes
    nothing finished (the stages' files untouched, the margin runs logged before the
    interruption reused, none repeated) and completes."""
    # 4 s: past the default's 2 s planned start, so the scenario's own run holds and the margins run
    text = DEFAULT_SCENARIO.read_text().replace("duration = 10.0", "duration = 4.0")
    scenario = tmp_path / "short.toml"
    scenario.write_text(text)
    out = tmp_path / "out"
    command = [sys.executable, "-m", "dvfc.reports", "report", str(scenario), "--out", str(out)]
    proc = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    logs = out / CACHE / "margins"
    logged = lambda: {p.name: p.read_text().splitlines() for p in logs.glob("*.jsonl")}  # noqa: E731
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline and proc.poll() is None and not any(logged().values()):
        time.sleep(0.01)
    proc.send_signal(signal.SIGINT)
    code, stderr = proc.wait(), proc.stderr.read()
    assert code == 130 and "--resume" in stderr.strip().splitlines()[-1], stderr
    assert not (out / "report.html").exists() and not (out / CACHE / "margins.pkl").exists()
    finished = {p: p.stat().st_mtime_ns for p in (out / CACHE).glob("*.pkl")}
    assert {p.stem for p in finished} >= {"simulation", "certificate", "verification"}
    before = logged()
    resumed = subprocess.run([*command, "--resume"], capture_output=True, text=True)
    assert resumed.returncode == 0, resumed.stderr
    assert all(p.stat().st_mtime_ns == stamp for p, stamp in finished.items()) and (out / "report.pdf").exists()
    after = logged()
    for name, lines in before.items():
        values = [json.loads(line)["value"] for line in after[name]]
        assert after[name][: len(lines)] == lines and len(values) == len(set(values)), name


@pytest.mark.slow
def test_as_implemented_section_states_the_limits(report):
    """Section "As implemented": the sampled run of the default example (500 Hz, 60 Hz camera,
    20 ms, RK4 between samples), labelled as a measurement, per joint its peak torque and speed against the URDF's
    limits (six rows, each ratio below 1: the default stays within them), and its feature
    tracks drawn inside the image border."""
    html = report[0].read_text()
    section = section_of(html, "<h2>6. As implemented</h2>")
    assert "500 Hz" in section and "60 Hz" in section and "20 ms" in section and "not certificates" in section
    assert "by RK4 in 2 steps per period" in section
    rows = section[section.index('<table id="limits">') :].split("</table>")[0].split("</tr>")[1:-1]
    assert len(rows) == 6
    cells = [re.findall(r'<td class="num">([0-9.e+-]+)</td>', row) for row in rows]
    ratios = [float(c[i]) for c in cells for i in (3, 6)]  # torque / effort, speed / velocity
    assert len(ratios) == 12 and max(ratios) < 1
    assert "Within the effort limits; within the velocity limits." in section
    assert re.search(r'<figure id="fig-implemented"><svg', section)


@pytest.mark.slow
def test_as_implemented_section_embeds_the_measured_margins(report):
    """Section "As implemented" shows the margins measured for the report (its cached stage):
    a row per parameter with the scenario's value, holds-at and breaks-at values and unit as
    measured, the criterion they were judged by, and the linear margins of the sampled loop
    linearised at rest (fact 14), each
    labelled as what it is (measured, or computed from eigenvalues)."""
    html = report[0].read_text()
    section = section_of(html, "<h2>6. As implemented</h2>")
    stored = pickle.loads((report[0].parent / CACHE / "margins.pkl").read_bytes())["value"]
    assert "dvfc margins" not in section and "Margins (measured)" in section and "not certificates" in section
    assert unescape(stored["criterion"]) in unescape(section)
    rows = section[section.index('<table id="margins">') :].split("</table>")[0].split("</tr>")[1:-1]
    assert [re.search(r"<td>(\w+)</td>", row).group(1) for row in rows] == list(stored["margins"])
    assert list(stored["margins"]) == list(PARAMETERS)
    for row, m in zip(rows, stored["margins"].values(), strict=True):
        cells = re.findall(r'<td class="num">([^<]+)</td>', row)
        expected = [m["range"][0], m["holds_at"], m["breaks_at"], m["range"][1]]
        assert cells == ["-" if v is None else f"{v:.4g}" for v in expected], row
        assert f"<td>{m['unit']}</td>" in row
    linear = unescape(section[section.index('<p id="linear-margins">') :].split("</p>")[0])
    assert stored["linear_margins"]["certified"]
    assert f"latency <= {stored['linear_margins']['margins']['latency']['value'] * 1e3:.4g} ms" in linear
    assert "not measured" in linear


@pytest.mark.slow
def test_page_one_gives_every_statement_its_own_status(report):
    """Page 1 lists every statement with the loop it is about and its own status (never one word
    for all): the L2 gain, the envelope's rate, visibility, the target's own speed, the start,
    the loop as implemented (fact 14), the measured margins, the exported program's replay, the
    checks; the banner is green exactly when no statement is uncertified, failed or inconclusive
    (on the default, started with the planned reference, every one is certified or passes)."""
    html = report[0].read_text()
    table = html[html.index('<table id="statements">') : html.index("</table>", html.index('<table id="statements">'))]
    rows = [[unescape(re.sub(r"<[^>]+>", "", cell)) for cell in re.findall(r"<td>(.*?)</td>", row, re.S)]
            for row in table.split("</tr>")[1:-1]]  # fmt: skip
    names, statuses = [r[0] for r in rows], [r[2] for r in rows]
    assert names[0] == "L2 gain (Theorem 2)" and "the start" in names and len(names) >= 8
    assert set(statuses) <= {"CERTIFIED", "NOT CERTIFIED", "DOES NOT APPLY", "PASS", "FAIL", "INCONCLUSIVE", "MEASURED"}
    assert statuses[names.index("margins of the loop as implemented")] == "MEASURED"
    program = next(n for n in names if n.startswith("the exported program"))
    assert statuses[names.index(program)] == "PASS"  # the exported program is the simulated one
    green = not {"NOT CERTIFIED", "FAIL", "INCONCLUSIVE"} & set(statuses)
    assert ('class="verdict pass"' in html) == green and green


@pytest.mark.slow
def test_banner_gives_the_best_certified_bound_and_its_certificate(report, tmp_path):
    """The banner's bound is the smallest certified one, with the certificate that gives it: the
    scaled storage's ``gamma_tight`` when below the paper's ``gamma`` (fact 4)."""
    target = tmp_path / "c.json"
    CliRunner().invoke(app, ["certify", str(DEFAULT_SCENARIO), "--no-lower-bounds", "--json", str(target)])
    point = json.loads(target.read_text())["points"][0]
    html = report[0].read_text()
    best = re.search(r'<span id="gamma-best">([^<]+)</span> \(([^)]*)', html)
    assert best.group(1) == f"{min(point['gamma'], point['gamma_tight']):.6g}"
    assert ("scaled storage" in best.group(2)) == (point["gamma_tight"] < point["gamma"])


@pytest.mark.slow
def test_as_implemented_section_says_which_statement_covers_which_part(report):
    """Section "As implemented" names the statement of each part: facts 7 and 10 for the ideal
    loop, fact 14 (local) for the sampled loop, measured margins and runs for the rest."""
    html = report[0].read_text()
    section = section_of(html, "<h2>6. As implemented</h2>")
    coverage = section[section.index('<p id="coverage">') :].split("</p>")[0]
    assert "ideal continuous loop by Theorem 2 and the envelope (facts 7 and 10" in coverage
    assert "sampled loop as implemented by fact 14 (local" in coverage
    assert "measured margins and runs of this section, which are measurements, not certificates" in coverage


@pytest.fixture(scope="module")
def cell_report(tmp_path_factory) -> tuple[Path, Path, str]:
    """The report of the cell example over 2 s with a campaign of 6 runs, made by the installed command line:
    the scenario, the scenario of the design it was synthesised from ([synthesized_from]) and the HTML."""
    folder = tmp_path_factory.mktemp("cell")
    data = tomllib.loads((EXAMPLES / "ur5_cell.toml").read_text())
    data["simulation"]["duration"] = 2.0
    data["report"] = {"campaign_runs": 6}
    scenario, before = folder / "cell.toml", folder / "before.toml"
    scenario.write_text(tomli_w.dumps(data))
    before_data = {**data, "gains": data["synthesized_from"]["gains"]}
    del before_data["synthesized_from"]
    before.write_text(tomli_w.dumps(before_data))
    made = subprocess.run([sys.executable, "-m", "dvfc.reports", "report", str(scenario), "--out", str(folder / "r")],
                          capture_output=True, text=True)  # fmt: skip
    assert made.returncode in (0, 1), made.stderr
    return scenario, before, unescape((folder / "r" / "report.html").read_text())


@pytest.mark.slow
def test_dispersions_section_states_the_campaigns_statement(cell_report, tmp_path):
    """A scenario with a [dispersion] (the cell example over 2 s, 6 runs): the report's section
    "Dispersions" has its four figures, and its statement, the same on page 1's row "dispersion
    campaign", equals the summary.json of ``dvfc campaign`` on the same scenario and runs."""
    scenario, _, html = cell_report
    campaign = CliRunner().invoke(app, ["campaign", str(scenario), "--runs", "6", "--out", str(tmp_path / "c")])
    assert campaign.exit_code in (0, 1), campaign.output
    statement = json.loads((tmp_path / "c" / "summary.json").read_text())["statement"]
    for figure in ("fig-campaign-ecdf", "fig-campaign-sensitivity", "fig-campaign-drivers", "fig-campaign-worst"):
        assert re.search(rf'<figure id="{figure}"><svg', html), figure
    shown = re.search(r'<p class="verdict measured" id="campaign-statement">(.*?)</p>', html, re.S)
    assert shown and shown.group(1) == statement
    row = re.search(r"<tr><td>dispersion campaign</td><td>[^<]*</td><td><span class=\"MEASURED\">MEASURED</span></td>"
                    r"<td>(.*?)</td></tr>", html)  # fmt: skip
    assert row and row.group(1) == statement


@pytest.mark.slow
def test_dispersions_section_sets_the_design_before_the_synthesis_beside_this_one(cell_report, tmp_path):
    """The cell example (2 s, 6 runs) names the design it was synthesised from ([synthesized_from]): the
    section "Dispersions" has both columns, each equal to ``dvfc campaign`` on that design's scenario with
    the same runs and seed (common random numbers: failures, P(fail) bound, worst closeness and its
    run), and the figure of both distributions."""
    scenario, before, html = cell_report
    table = re.search(r'<table id="campaign-before-after">(.*?)</table>', html, re.S).group(1)
    cells = {row[0]: row[1:] for row in (re.findall(r"<t[hd][^>]*>(.*?)</t[hd]>", r) for r in table.split("</tr>"))
             if row}  # fmt: skip
    assert cells[""] == ["before the synthesis", "this design"]
    for column, path in enumerate((before, scenario)):
        out = tmp_path / f"c{column}"
        campaign = CliRunner().invoke(app, ["campaign", str(path), "--runs", "6", "--out", str(out)])
        assert campaign.exit_code in (0, 1), campaign.output
        summary = json.loads((out / "summary.json").read_text())
        worst = summary["worst"][0]
        assert cells["failures"][column] == f"{summary['failures']} of {summary['runs']}"
        assert cells["P(fail) upper bound at 95% confidence (clopper-pearson, one-sided)"][column] == (
            f"{summary['p_fail_upper']:.3g}")
        assert cells["worst closeness to failing (run)"][column] == f"{worst['closeness']:.4g} (run {worst['run']})"
    assert cells["worst closeness to failing (run)"][0] != cells["worst closeness to failing (run)"][1]
    assert re.search(r'<figure id="fig-campaign-before"><svg', html)


@pytest.mark.slow
def test_scenario_table_describes_the_loop_that_was_run(report):
    """The scenario table's simulation row of the default example names the loop as implemented
    (500 Hz, 60 Hz camera, 20 ms, e_e from the image, RK4) and the paper's continuous loop of
    sections 3-5, never the bare "e_e ideal, CVODES" of a loop that was not run."""
    html = report[0].read_text()
    cell = re.search(r'<td id="loop-run">(.*?)</td>', html, re.S).group(1)
    assert "e_e ideal" not in cell
    assert "torques at 500 Hz held, images at 60 Hz, latency 20 ms, e_e from the image (21)" in cell
    assert "RK4 with 2 steps per control period" in cell and "the paper's continuous loop" in cell


CALIBRATION = {
    "image_width": 1280, "image_height": 1024, "camera_name": "cell", "distortion_model": "plumb_bob",
    "camera_matrix": {"rows": 3, "cols": 3, "data": [805.0, 0, 642.5, 0, 801.0, 510.25, 0, 0, 1]},
    "distortion_coefficients": {"rows": 1, "cols": 5, "data": [-0.05, 0.01, 0.0005, -0.0003, 0.0]},
}  # fmt: skip
"""A ROS camera_info calibration: fx 805 px, fy 801 px, principal point (642.5, 510.25) px, plumb-bob distortion."""


@pytest.fixture(scope="module")
def solved(tmp_path_factory, monkeypatch_module) -> tuple[str, dict]:
    """The report of the default scenario with what the scenario table must state rather than
    copy: ``q0 = "auto"``, the camera from a calibration file, friction and a payload on the plant
    (2 s, CasADi's virtual machine, the margins not measured); its HTML and its stored run as implemented."""
    import yaml

    from dvfc.reports import document

    root = tmp_path_factory.mktemp("solved")
    (root / "camera.yaml").write_text(yaml.safe_dump(CALIBRATION))
    data = tomllib.loads(DEFAULT_SCENARIO.read_text())
    data["robot"]["q0"] = "auto"
    data["camera"] = {"calibration": "camera.yaml"}
    data["simulation"] |= {"duration": 2.0, "jit": False}
    data["plant"] = {"friction": {"viscous": 0.3, "coulomb": 0.1}, "payload": {"mass": 0.2}}
    (root / "solved.toml").write_text(tomli_w.dumps(data))
    monkeypatch_module.setattr(document, "measure_margins", lambda *args: {"reason": "not measured here"})
    result = CliRunner().invoke(app, ["report", str(root / "solved.toml"), "--out", str(root / "out")])
    assert result.exit_code in (0, 1) and isinstance(result.exception, SystemExit | None), result.exception
    stored = pickle.loads((root / "out" / CACHE / "implemented.pkl").read_bytes())["value"]
    return (root / "out" / "report.html").read_text(), {"q0": stored["q"][0], "pdf": root / "out" / "report.pdf"}


@pytest.fixture(scope="module")
def monkeypatch_module():
    with pytest.MonkeyPatch.context() as patch:
        yield patch


def cell(html: str, name: str) -> str:
    """The text of the scenario table's cell ``name`` (its id), tags removed."""
    found = re.search(rf'<td id="{name}">(.*?)</td>', html, re.S)
    assert found, name
    return " ".join(unescape(re.sub(r"<[^>]+>", "", found.group(1))).split())


@pytest.mark.slow
def test_a_solved_q0_is_shown_as_the_configuration_run_and_said_to_be_solved(solved):
    """``q0 = "auto"``: the scenario table gives the configuration inverse kinematics solved for
    (the one the run starts from) and says it was solved, in the HTML and the PDF."""
    html, stored = solved
    row = cell(html, "q0")
    assert row.startswith("q0 = [" + ", ".join(f"{v:.4g}" for v in stored["q0"]) + "] rad")
    assert 'solved (robot.q0 = "auto") by inverse kinematics' in row
    text = subprocess.run(["pdftotext", str(stored["pdf"]), "-"], capture_output=True, text=True, check=True).stdout
    assert 'solved (robot.q0 = "auto")' in " ".join(text.split())


@pytest.mark.slow
def test_the_camera_row_states_the_calibrated_intrinsics(solved):
    """The camera row gives fx, fy, the principal point, the distortion coefficients, the image
    size and the calibration file they came from (never a focal length of "-")."""
    row = cell(solved[0], "camera")
    assert "fx = 805 px, fy = 801 px, principal point (642.5, 510.25) px" in row
    assert "[k1, k2, p1, p2, k3] = [-0.05, 0.01, 0.0005, -0.0003, 0]" in row
    assert "image 1280 x 1024 px; from the calibration file camera.yaml" in row
    assert "focal length" not in row


@pytest.mark.slow
def test_what_acts_on_the_plant_is_listed_among_the_disturbances(solved):
    """With ``[plant]`` friction and a payload the disturbances row names them as what acts on the
    plant (with their values), besides the target's motion, never "none"."""
    row = cell(solved[0], "disturbances")
    assert row.startswith("the target's motion (circle); acting on the plant of the loop as implemented")
    assert "viscous b = [0.3, 0.3, 0.3, 0.3, 0.3, 0.3] N m s/rad, Coulomb c = [0.1, 0.1, 0.1, 0.1, 0.1, 0.1] N m" in row
    assert "a payload of 0.2 kg on the camera link" in row
    assert "none" not in row


@pytest.mark.slow
def test_the_observer_row_says_where_its_start_came_from(solved):
    """With ``[start] observer = "image"`` the [observer] error is unused: the row says so."""
    assert "gbar(0) from the first image" in cell(solved[0], "observer")


@pytest.mark.slow
def test_the_controller_section_states_the_exports_digest_replay_step_times_and_coverage(report, tmp_path):
    """Section 7 of the report: the program's SHA-256 equal to ``dvfc export``'s for the same
    scenario, the replay over its 4 s (2000 samples at 500 Hz) identical to the bit, the compiled
    step timed over 1e4 calls without and with an image in wall and thread CPU time (0 <= min <= median <=
    p99.9 <= max, the max positive), and what fact 14 for the program's loop (facts 14, 22) says of it."""
    html = unescape(report[0].read_text())
    section = section_of(html, '<h2 id="controller">7. The controller that runs</h2>')
    scenario = report[0].parent / "ur5_circle.toml"  # the report's own scenario
    exported = CliRunner().invoke(app, ["export", str(scenario), "--out", str(tmp_path / "c"), "--json", "-"])
    assert exported.exit_code == 0, exported.output
    digest = json.loads(exported.stdout)["sha256"]
    assert re.search(r'<code id="controller-sha256">([0-9a-f]{64})</code>', section).group(1) == digest
    paragraph = section[section.index('id="controller-replay"') :].split("</p>")[0]
    replay = " ".join(re.sub(r"<[^>]+>", "", paragraph).split())
    assert f"{REPORT_DURATION * 500:.0f} samples" in replay and "largest torque difference 0 N m" in replay
    assert "joints within 0 of the Python step's" in replay and replay.rstrip().endswith("PASS.")
    table = section[section.index('<table id="controller-timing">') :].split("</table>")[0]
    rows = [re.findall(r"<td[^>]*>(.*?)</td>", r) for r in table.split("</tr>")[1:] if "<td" in r]
    assert [r[0] for r in rows] == [f"{clock}, {image}" for clock in ("wall time", "thread CPU time")
                                    for image in ("no image", "an image at every call")]  # fmt: skip
    for row in rows:
        calls, *times = row[1:]
        assert calls == "10000"
        values = [float(t) for t in times]  # a clock coarser than a step reads 0 for some calls (seen: thread CPU time)
        assert 0 <= values[0] <= values[1] <= values[2] <= values[3] and values[3] > 0
    coverage = " ".join(section[section.index('id="controller-coverage"') :].split("</p>")[0].split())
    assert "Fact 14 for the program's loop (docs/math.md, facts 14 and 22)" in coverage
    implemented = dvfc.certify(dvfc.load(scenario), lower_bounds=False).points[0].implemented
    assert f"rho = {implemented['program_rho']:.6g} (below 1: local exponential stability of the loop the program" in (
        coverage)
    assert f"observer integrates (12) continuously, rho = {implemented['rho']:.6g}" in coverage
