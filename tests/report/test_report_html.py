"""index.html: sections, tables, relative PNG images that exist, and a real render in headless Chromium."""

from __future__ import annotations

import html as html_lib
import re
import shutil
import subprocess

from matplotlib.image import imread
import pytest
from report_helpers import SECTION_IDS, entry, image_sources

from pkf.report.html import SECTION_IDS as MODULE_SECTION_IDS

CHROMIUM_NAMES = ("chromium", "chromium-browser")

# Written into a copy of index.html: after the page (and so every image) has loaded,
# record each image's natural width and the number of images in the DOM, which
# `chromium --dump-dom` then prints.
_PROBE = """<script>
window.addEventListener("load", function () {
  var images = document.querySelectorAll("img");
  images.forEach(function (img) {
    img.setAttribute("data-natural-width", String(img.naturalWidth));
  });
  document.body.setAttribute("data-images-checked", String(images.length));
});
</script>"""


def test_section_ids_are_stable():
    assert MODULE_SECTION_IDS == SECTION_IDS


@pytest.mark.parametrize("which", ["telescope", "bs"])
def test_index_html(which, telescope_report, bs_report):
    out, summary = {"telescope": telescope_report, "bs": bs_report}[which]
    text = (out / "index.html").read_text()
    for section in SECTION_IDS:
        assert f'<section id="{section}">' in text
    # self-contained: no URL with a scheme, images beside the page
    assert not re.search(r'(src|href)="[a-z]+:', text)
    assert "http://" not in text and "https://" not in text
    sources = [html_lib.unescape(s) for s in image_sources(text)]
    assert "resolution.png" in sources and "chi2.png" in sources
    assert any(s.startswith("pulls_") for s in sources)
    for source in sources:
        assert "/" not in source and (out / source).is_file()
        assert (out / source).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    pngs = sorted(p.name for p in out.glob("*.png"))
    assert sorted(sources) == pngs
    if which == "bs":
        assert "mass.png" in sources and "efficiency.png" in sources
        sigma = entry(summary, "reference")["mass"]["fit"]["sigma"]
        assert f"{sigma:.2f}" in text
    else:
        assert "mass.png" not in sources  # no B_s decay in a gun sample: said, not drawn
        assert "no B_s" in text
    # a number from each table is on the page
    pull_width = entry(summary, "reference")["pulls"]["parameters"]["x"]["width"]
    assert f"{pull_width:.3f}" in text
    assert f"{entry(summary, 'reference')['timing']['tracks_per_s']:.4g}" in text


def _chromium() -> str:
    for name in CHROMIUM_NAMES:
        path = shutil.which(name)
        if path:
            return path
    pytest.skip("headless-browser test skipped: no `chromium` on PATH (install the Debian package: "
                "apt-get update && apt-get install -y chromium)")


def _render(chromium: str, page, profile) -> str:
    """The DOM of `page` after load, as headless Chromium serialises it."""
    cmd = [chromium, "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
           "--disable-component-update", "--disable-sync", "--no-first-run", "--disable-extensions",
           f"--user-data-dir={profile}", "--virtual-time-budget=5000", "--dump-dom", page.as_uri()]
    result = subprocess.run(cmd, capture_output=True, text=True, timeout=120, stdin=subprocess.DEVNULL)
    assert result.returncode == 0, result.stderr[-2000:]
    return result.stdout


def _screenshot(chromium: str, page, out, profile, width: int = 1600, height: int = 12000) -> None:
    """A PNG screenshot of `page` (the top `height` pixels) by headless Chromium."""
    cmd = [chromium, "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
           "--disable-component-update", "--disable-sync", "--no-first-run", "--disable-extensions",
           "--hide-scrollbars", f"--user-data-dir={profile}", "--virtual-time-budget=5000",
           f"--window-size={width},{height}", f"--screenshot={out}", page.as_uri()]
    result = subprocess.run(cmd, capture_output=True, text=True, timeout=120, stdin=subprocess.DEVNULL)
    assert result.returncode == 0 and out.is_file(), result.stderr[-2000:]


def _image_widths(dom: str) -> list[int]:
    widths = []
    for tag in re.findall(r"<img\b[^>]*>", dom):
        match = re.search(r'data-natural-width="(\d+)"', tag)
        widths.append(int(match.group(1)) if match else -1)
    return widths


def test_report_renders_in_headless_chromium(bs_report, tmp_path):
    chromium = _chromium()
    out, _ = bs_report
    site = tmp_path / "site"
    shutil.copytree(out, site)
    text = (site / "index.html").read_text()
    n_images = len(image_sources(text))
    assert n_images >= 5
    probe = site / "probe.html"
    probe.write_text(text.replace("</body>", _PROBE + "</body>"))

    dom = _render(chromium, probe, tmp_path / "profile")
    assert f'data-images-checked="{n_images}"' in dom, "the page did not finish loading"
    widths = _image_widths(dom)
    assert len(widths) == n_images and all(w > 0 for w in widths), widths
    for section in SECTION_IDS:
        assert re.search(rf'<section id="{section}"', dom), section

    # the per-track-type figures (issue 17.2) are on the page and load
    sources = image_sources(text)
    for figure in ("chi2_types.png", "efficiency_types.png"):
        assert figure in sources
        assert widths[sources.index(figure)] > 0, figure

    # a screenshot of the whole page: every figure is painted (not a blank page)
    shot = tmp_path / "page.png"
    _screenshot(chromium, site / "index.html", shot, tmp_path / "profile")
    pixels = imread(shot)
    assert pixels.shape[0] >= 4000, pixels.shape  # the page is tall: figures one under another
    painted = (pixels[..., :3] < 0.9).any(axis=2)  # not white
    rows = painted.any(axis=1)
    assert rows.mean() > 0.3, rows.mean()

    # the probe does see a broken image: remove one PNG and render again
    (site / "mass.png").unlink()
    widths = _image_widths(_render(chromium, probe, tmp_path / "profile"))
    assert sorted(w > 0 for w in widths) == [False] + [True] * (n_images - 1)
