"""The HTML report in a real browser (headless Chromium): every figure loads, nothing is
fetched from anywhere, and a figure that does not decode is caught by the same check."""

import re
import shutil

from click.testing import CliRunner

from browser import chromium_page
from report_page import Page
from swarmraft.cli import main

pytest_plugins = ("report_folders",)  # the folders' fixtures

#: per <img>: its name, whether it finished loading, and its decoded width (0: it did not decode)
IMAGES_JS = "Array.from(document.images).map(i => [i.dataset.name, i.complete, i.naturalWidth])"


def open_report(path):
    """(images as IMAGES_JS gives them, every URL the page asked for) of the report at ``path``."""
    requests: list[str] = []
    with chromium_page() as page:
        page.on("request", lambda r: requests.append(r.url))
        page.goto(path.resolve().as_uri(), wait_until="load")
        images = page.evaluate(IMAGES_JS)
    return images, requests


def not_loaded(images) -> list[str]:
    return [name for name, complete, width in images if not (complete and width > 0)]


def test_every_figure_of_the_report_loads_in_chromium(mission_dir, tmp_path):
    folder = tmp_path / "m"
    shutil.copytree(mission_dir, folder, ignore=shutil.ignore_patterns("report.html"))
    r = CliRunner().invoke(main, ["figure", "animation", str(folder), "--every", "10"])
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(main, ["report", str(folder)])
    assert r.exit_code == 0, r.output
    report = folder / "report.html"
    figures = sorted(p.name for p in (folder / "figures").iterdir())
    assert "animation.gif" in figures and len(figures) == 5

    images, requests = open_report(report)

    assert sorted(name for name, _, _ in images) == figures
    assert not_loaded(images) == []
    assert requests == [report.resolve().as_uri()]  # the page itself; the figures are data: URIs

    # the same check on the same report with one figure's data broken: that figure is caught
    page = Page(report.read_text())
    src = next(a["src"] for t, a in page.tags if t == "img" and a["data-name"] == "swarm_maps.png")
    head, data = src.split(",", 1)
    bad = head + "," + re.sub(r"[A-Za-z]", "A", data[:4000]) + data[4000:]  # a PNG no longer
    broken = tmp_path / "broken.html"
    broken.write_text(report.read_text().replace(src, bad))

    images, _ = open_report(broken)

    assert not_loaded(images) == ["swarm_maps.png"]
