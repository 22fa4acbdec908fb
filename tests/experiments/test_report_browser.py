"""The `--quick` report, built by the command line and opened in headless Chromium (Playwright)."""
import csv
import json
import re
import shutil

import pytest

from probvis.cli import main

CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync"]


@pytest.fixture(scope="module")
def quick_report(tmp_path_factory):
    out = tmp_path_factory.mktemp("quick")
    assert main(["experiment", "--quick", "-o", str(out), "-q"]) == 0
    return out


def chromium():
    try:
        from playwright.sync_api import sync_playwright  # noqa: F401
    except ImportError:
        pytest.skip("playwright is not installed (pip install -e '.[test]')")
    path = shutil.which("chromium") or shutil.which("chromium-browser")
    if path is None:
        pytest.skip("no Chromium on this machine (Debian: apt-get install chromium; .ci/run installs it)")
    return path


def test_quick_report_files(quick_report):
    rows = list(csv.DictReader((quick_report / "results.csv").open()))
    assert len(rows) == 2 * 7 * 5  # scenes x methods x shadow-ray counts
    assert {r["method"] for r in rows} == {"exact", "om-bvh", "om-list", "standard", "shifted", "power", "adaptive"}
    doc = json.loads((quick_report / "results.json").read_text())
    assert set(doc["targets"]) == {"box-city", "canopy"}
    page = (quick_report / "index.html").read_text()
    assert not re.search(r"""(src|href)\s*=\s*['"]?(https?:)?//""", page), "the page must not load network resources"
    for ref in re.findall(r"""(?:src|href)=['"]?([^'" >]+)""", page):
        assert (quick_report / ref).is_file(), ref


def test_quick_report_in_chromium(quick_report):
    from playwright.sync_api import sync_playwright

    exe = chromium()
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=exe, args=CHROMIUM_ARGS)
        try:
            page = browser.new_page(viewport={"width": 1400, "height": 900})
            problems = []
            page.on("console", lambda m: problems.append(m.text) if m.type in ("error", "warning") else None)
            page.on("pageerror", lambda e: problems.append(str(e)))
            page.on("requestfailed", lambda r: problems.append(f"failed to load {r.url}"))
            page.goto((quick_report / "index.html").as_uri())
            page.wait_for_load_state("load")
            assert page.locator("#paper-table tbody tr").count() == 2 * 7  # scenes x methods
            # at 1400 px the page needs no sideways scrolling and the comparison sits centred in its panel
            assert page.evaluate("document.documentElement.scrollWidth <= window.innerWidth")
            table = page.locator("#paper-table").bounding_box()
            assert table["x"] >= 0 and table["x"] + table["width"] <= 1400
            stage = page.locator(".viewer .stage").first.bounding_box()
            image = page.locator(".viewer canvas").first.bounding_box()
            assert abs((image["x"] + image["width"] / 2) - (stage["x"] + stage["width"] / 2)) < 2
            assert abs((image["y"] + image["height"] / 2) - (stage["y"] + stage["height"] / 2)) < 2
            assert image["height"] > 0.95 * stage["height"] or image["width"] > 0.95 * stage["width"]
            broken = page.evaluate("Array.from(document.images).filter(i => !(i.complete && i.naturalWidth > 0))"
                                   ".map(i => i.src)")
            assert broken == []
            viewer = page.locator(".viewer").first
            canvas = viewer.locator("canvas")
            pixels = "c => Array.from(c.getContext('2d').getImageData(0, 0, c.width, c.height).data).join(',')"
            before, state = canvas.evaluate(pixels), canvas.get_attribute("data-current")
            viewer.locator("select").nth(2).select_option("reference")  # right-hand image: the reference
            assert canvas.get_attribute("data-current") != state
            assert canvas.evaluate(pixels) != before
            viewer.locator("select").nth(3).select_option("signed")
            assert canvas.get_attribute("data-current").endswith("|signed")
            assert problems == []
        finally:
            browser.close()
