"""The documentation site builds with ``mkdocs build --strict`` (``make docs``): no broken link or anchor, no page
missing from the nav, no API page griffe warns about, and every results table a family page includes is there.

The family pages include their results from ``docs/results/<table>/<table>.md`` (pymdownx.snippets), so the test
checks that a number of the table's JSON reaches the built HTML: the include happened, nothing was copied by hand.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from factories import REPO

FAMILY_PAGES = ["darkroom_iprl", "darkroom_tprl", "reach_iprl", "reach_tprl", "dueling_bandits"]
INCLUDE = re.compile(r'^--8<-- "docs/results/([\w-]+)/([\w-]+)\.md"$', re.MULTILINE)
REPRODUCE = re.compile(r"icprl reproduce ([a-z][\w-]*)")


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("site")
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1", "OMP_NUM_THREADS": "1"}
    proc = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(out)],
                          cwd=REPO, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, f"mkdocs build --strict failed:\n{proc.stdout[-3000:]}\n{proc.stderr[-6000:]}"
    return out


def test_the_site_has_its_index_and_every_family_page(site):
    assert (site / "index.html").is_file()
    for page in FAMILY_PAGES:
        assert (site / "families" / page / "index.html").is_file(), page
    assert (site / "reference" / "methods" / "index.html").is_file()


def test_a_family_page_shows_the_numbers_of_its_results_json(site):
    # ICPO's held-out return per context quality (mean ± sem over training seeds) as darkroom_ipref.json holds it
    results = json.loads((REPO / "docs/results/darkroom_ipref/darkroom_ipref.json").read_text())["results"]["ICPO"]
    html = (site / "families/darkroom_iprl/index.html").read_text()
    for quality in ("low", "medium", "high"):
        cell = f"{results[quality]['return']:.1f} ± {results[quality]['return_sem']:.1f}"
        assert f"<td>{cell}</td>" in html, f"ICPO's {quality} return {cell} is not on the DarkRoom I-PRL page"


def test_every_include_names_an_existing_table_and_every_command_an_experiment():
    for page in FAMILY_PAGES:
        text = (REPO / "docs/families" / f"{page}.md").read_text()
        includes = INCLUDE.findall(text)
        assert includes, f"{page}.md includes no results table"
        for folder, name in includes:
            assert (REPO / "docs/results" / folder / f"{name}.md").is_file(), (page, folder, name)
        for table in set(REPRODUCE.findall(text)):
            assert (REPO / "configs/experiment" / f"{table}.yaml").is_file(), (page, table)


def test_every_results_table_on_a_family_page_names_its_command_and_budget():
    # the budget is quoted from the experiment file, so the page cannot drift from it
    for page in FAMILY_PAGES:
        text = (REPO / "docs/families" / f"{page}.md").read_text()
        for table in {folder for folder, _ in INCLUDE.findall(text)}:
            budget = yaml.safe_load((REPO / "configs/experiment" / f"{table}.yaml").read_text())["budget"]
            assert f"(`configs/experiment/{table}.yaml`): {budget}" in text, (page, table, budget)
            assert f"icprl reproduce {table}\n" in text, (page, table)

