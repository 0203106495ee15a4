"""The sweep report in a real headless browser (the system's Chromium, driven by Playwright): the page loads
without a console error or a failed request, every image decodes, and every expected plot is on the page.

Needs /usr/bin/chromium (Debian: ``apt-get install chromium``, part of ``make system-packages``) and the
``playwright`` Python package (the ``dev`` extra); Playwright's own browser downloads are never used."""

from __future__ import annotations

from pathlib import Path

import pytest

from simtest.sweeps.grid import SweepConfig, run_sweep

CHROMIUM = Path("/usr/bin/chromium")

pytestmark = pytest.mark.skipif(not CHROMIUM.exists(),
                                reason=f"the browser check needs Chromium at {CHROMIUM} "
                                       f"(apt-get install chromium, or make system-packages)")


@pytest.fixture(scope="module")
def report(small_dataset, tmp_path_factory):
    """A small real sweep over the session's dataset: occlusion, a corruption and a depth preset, with grasp
    episodes, so the page has every kind of plot and example picture."""
    cfg = SweepConfig.from_dict({
        "seed": 0,
        "estimators": [{"name": "oracle", "estimator": "oracle", "options": {"rot_noise_deg": 2.0}},
                       {"name": "oracle-noisy", "estimator": "oracle",
                        "options": {"rot_noise_deg": 15.0, "trans_noise_mm": 25.0}}],
        "dataset": {"path": str(small_dataset), "max_images": 2},
        "factors": {"occlusion": ["L1"], "corruptions": ["fog"], "depth_noise": ["realsense-d435"]},
        "grasp": {"episodes": 1, "width": 96, "height": 72},
    })
    out = tmp_path_factory.mktemp("browser-sweep") / "s"
    run_sweep(cfg, out, progress=False)
    return cfg, out / "report.html"


def test_report_loads_in_headless_chromium_with_every_image(report):
    from playwright import sync_api  # the dev extra

    cfg, page_path = report
    errors: list[str] = []
    with sync_api.sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=str(CHROMIUM), headless=True, args=["--no-sandbox"])
        try:
            page = browser.new_page()
            page.on("console", lambda m: errors.append(f"console {m.type}: {m.text}") if m.type == "error" else None)
            page.on("pageerror", lambda exc: errors.append(f"page error: {exc}"))
            page.on("requestfailed", lambda r: errors.append(f"request failed: {r.url[:80]}"))
            page.goto(page_path.as_uri(), wait_until="load")
            images = page.evaluate("Array.from(document.images).map(i => ({alt: i.alt, complete: i.complete, "
                                   "w: i.naturalWidth, h: i.naturalHeight, "
                                   "figure: i.closest('figure') ? i.closest('figure').id : ''}))")
            title = page.title()
            tables = page.locator("table").count()
        finally:
            browser.close()
    assert title == "simtest robustness report"
    assert errors == []
    assert images and all(i["complete"] and i["w"] > 0 and i["h"] > 0 for i in images), images
    expected = {f"plot-{m}" for m in cfg.metrics} | {"plot-grasp-occlusion", "plot-error-vs-grasp"}
    assert expected <= {i["figure"] for i in images}
    examples = [i for i in images if not i["figure"]]
    assert len(examples) >= 4  # clean, L1, fog-4, and the depth pictures of depth-realsense-d435
    assert tables == len(cfg.metrics) + 1
