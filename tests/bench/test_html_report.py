"""report.html: one self-contained file (plots inline) that headless Chromium renders."""

from __future__ import annotations

import shutil
import subprocess

import pytest

from omnibench.campaign.html_report import write_html

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")

REPORT = """# omnibench campaign report

- port: `sim://`

## Analysis

| parameter | value | std. error | verdict |
|---|---|---|---|
| b | 0.5 | 0.001 | identified |
| C_r | 0 | – | at bound |

![sweep](plots/sweep.png)
"""


def _report(tmp_path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    (tmp_path / "plots").mkdir()
    fig, ax = plt.subplots(figsize=(4, 3))
    ax.plot([0, 1, 2], [0, 1, 4], "r-", lw=6)
    fig.savefig(tmp_path / "plots" / "sweep.png", dpi=60)
    plt.close(fig)
    md = tmp_path / "report.md"
    md.write_text(REPORT, encoding="utf-8")
    return write_html(md)


def test_html_is_one_file_with_plots_inline(tmp_path) -> None:
    html = _report(tmp_path).read_text(encoding="utf-8")
    assert '<img src="data:image/png;base64,' in html and "plots/sweep.png" not in html
    assert "<table>" in html and "<td>at bound</td>" in html


@pytest.mark.skipif(CHROMIUM is None, reason="chromium is not installed (apt-get install chromium)")
def test_html_report_renders_in_headless_chromium(tmp_path) -> None:
    page = _report(tmp_path)
    (tmp_path / "plots" / "sweep.png").unlink()  # the page must not need the plot files
    shot = tmp_path / "shot.png"
    args = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
            f"--user-data-dir={tmp_path / 'profile'}", "--window-size=900,700"]
    dom = subprocess.run([*args, "--dump-dom", page.as_uri()], capture_output=True, text=True, timeout=120)
    assert "at bound" in dom.stdout and "<table>" in dom.stdout
    subprocess.run([*args, f"--screenshot={shot}", page.as_uri()], capture_output=True, timeout=120)
    import matplotlib.image as mpimg

    img = mpimg.imread(shot)
    red = (img[..., 0] > 0.8) & (img[..., 1] < 0.3) & (img[..., 2] < 0.3)
    assert red.sum() > 50  # the inlined plot's red line was drawn


def _campaign_results() -> dict:
    """A campaign's results as run_campaign records them: a declared fit, its energy error, and a
    diagnosis that added the driver deadband and refitted R_a (the issue's deadband figures)."""
    fit = {"parameters": {
        "R_a": {"value": 3.466, "se": 0.039, "ci95": [3.39, 3.54], "unit": "ohm", "verdict": "identified", "identifiable": True},
        "C_r": {"value": 0.0097, "se": 0.0004, "ci95": [0.0089, 0.0105], "unit": "1", "verdict": "identified", "identifiable": True}},
        "error_by_procedure": {"sweep": 0.05}}
    diag = {"selected": [{"effect": "driver_deadband", "title": "Motor-driver deadband",
                          "parameters": {"driver_deadband.u_0": {"value": 0.04012, "se": 0.00006, "unit": "1"}}}],
            "before": {"sweep": {"nrmse": 0.062}}, "after": {"sweep": {"nrmse": 0.0021}},
            "extended_fit": {"R_a": {"value": 1.8441, "se": 0.0123}, "C_r": {"value": 0.0202, "se": 0.0006},
                             "driver_deadband.u_0": {"value": 0.04012, "se": 0.00006}},
            "written": {"model": "model_diagnose.toml", "plots": []}}
    return {"port": "sim://", "robot_file": "default", "tool_version": "test", "procedures": {}, "host_seconds": 1.0,
            "analysis": {"fit": {"status": "ok", "command": "omnibench fit", "result": fit},
                         "validate-energy": {"status": "ok", "command": "omnibench validate-energy",
                                             "result": {"runs": [], "mean_abs_error_pct": 5.48}},
                         "diagnose": {"status": "ok", "command": "omnibench diagnose", "result": diag,
                                      "validate_energy": {"status": "ok", "command": "omnibench validate-energy",
                                                          "result": {"runs": [], "mean_abs_error_pct": 0.21}}}}}


def test_report_opens_with_the_diagnosed_model(tmp_path) -> None:
    from omnibench.campaign.run import write_report
    from omnibench.model import default_robot

    text = write_report(_campaign_results(), tmp_path, default_robot()).read_text(encoding="utf-8")
    answer = text[:text.index("## The campaign")]  # the first section, before any procedure or analysis detail
    assert "## The answer" in answer and "`driver_deadband`" in answer
    assert "| R_a | 1.844 ± 0.012 | [1.820, 1.868] | ohm | 3.466 ± 0.039 |" in answer  # rounded to the SE
    assert "| C_r | 0.02020 ± 0.00060 |" in answer and "dimensionless" in answer and "| 1 |" not in answer
    assert "5.48 % with the declared fit → **0.21 %** with the diagnosed model" in answer
    assert "sweep 6.2 % → 0.21 %" in answer
    assert text.index("## The answer") < text.index("## Procedures") < text.index("## Analysis")


@pytest.mark.skipif(CHROMIUM is None, reason="chromium is not installed (apt-get install chromium)")
def test_first_screen_of_the_html_report_holds_the_coefficient_table(tmp_path) -> None:
    from omnibench.campaign.run import write_report
    from omnibench.model import default_robot

    page = write_html(write_report(_campaign_results(), tmp_path, default_robot()))
    # where the browser lays the coefficient table out, written into the page for --dump-dom to read
    probe = tmp_path / "probe.html"
    probe.write_text(page.read_text(encoding="utf-8").replace(
        "</body>", "<script>const t = document.querySelector('table'); const r = t.getBoundingClientRect();"
        "document.body.setAttribute('data-table', t.innerText.includes('R_a') + ' ' + r.top + ' ' + r.bottom);"
        "</script></body>"), encoding="utf-8")
    args = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
            f"--user-data-dir={tmp_path / 'profile'}", "--window-size=1280,800"]
    dom = subprocess.run([*args, "--dump-dom", probe.as_uri()], capture_output=True, text=True, timeout=120)
    import re

    m = re.search(r'data-table="(\w+) ([\d.]+) ([\d.]+)"', dom.stdout)
    assert m is not None, dom.stdout[:500]
    assert m.group(1) == "true" and float(m.group(3)) <= 800  # the whole table on the first screen
    shot = tmp_path / "shot.png"
    subprocess.run([*args, f"--screenshot={shot}", page.as_uri()], capture_output=True, timeout=120)
    assert shot.is_file() and shot.stat().st_size > 10_000
