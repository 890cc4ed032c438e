"""Each view drawn by the browser from the package's own assets (no request leaves the server), with its
screenshot: ``ICPRL_LABEL_SCREENSHOTS=docs/figures pytest tests/labelling/test_views.py`` writes the docs' ones."""

from __future__ import annotations

import pytest

# view -> (CSS selector of what must be drawn, how many, words the legend holds)
VIEWS = {
    "darkroom_steps": ("svg line.first, svg line.second, svg circle.first, svg circle.second", 2, "Goal G at"),
    "darkroom_trajectories": ("svg polyline.path", 2, "Steps on the goal"),
    "reach_trajectories": ("svg polyline.path", 4, "Final distance to the goal"),
    "bandit_duels": ("svg rect.goal, svg rect.first, svg rect.second", 30, "along θ"),
}


@pytest.mark.parametrize("view", sorted(VIEWS))
def test_each_view_is_drawn_from_local_assets(browser, servers, tmp_path, screenshots, view):
    selector, count, words = VIEWS[view]
    server = servers("--session", str(tmp_path / view), "--view", view, "--pairs", "3", "--seed", "1")
    page = browser.new_page(viewport={"width": 1000, "height": 700})
    requested = []
    page.on("request", lambda r: requested.append(r.url))
    page.goto(f"{server.url}&annotator=screenshot")
    page.wait_for_selector("body[data-done='0']", state="attached")
    assert len(page.query_selector_all(selector)) == count
    assert words in page.inner_text("#legend")
    assert page.inner_text("#count") == "0 / 3"
    origin = server.url.split("/?")[0]
    assert requested and all(url.startswith(origin + "/") for url in requested), requested
    page.wait_for_timeout(700)  # the episodes' replay moves on a few steps
    page.screenshot(path=screenshots / f"label_{view}.png")
