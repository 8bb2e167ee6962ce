"""report.html: one self-contained file (plots inline) that headless Chromium renders."""

from __future__ import annotations

import shutil
import subprocess

import pytest

from omnibench.bench.html_report import write_html

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
