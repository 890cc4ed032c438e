"""The generated docs equal a fresh render of the results JSON: no number in them can drift from its data."""

from __future__ import annotations

import json
import re

import pytest
from factories import REPO

from icprl_lightning.reproduce import render
from icprl_lightning.reproduce.statistics import difference, scores_of


@pytest.fixture(autouse=True)
def at_the_repository(monkeypatch):
    monkeypatch.chdir(REPO)


def test_every_generated_page_equals_a_fresh_render():
    stale = render.stale()
    assert not stale, (f"{', '.join(map(str, stale))} differ from what `icprl reproduce --render` writes from "
                       "docs/results: run it and commit the pages")


def test_every_table_folder_with_an_evaluation_has_a_summary_and_the_index_lists_it():
    index = (REPO / "docs/results/index.md").read_text()
    for folder in sorted(p for p in (REPO / "docs/results").iterdir() if p.is_dir()):
        assert f"| {folder.name} |" in index
        if render.evaluations_in(folder):
            assert (folder / "summary.md").exists(), folder


def test_the_claims_table_has_at_most_twelve_rows_each_read_from_its_json():
    claims = render.read_claims()
    assert 0 < len(claims) <= 12
    readme = (REPO / "README.md").read_text()
    start, end = render.README_MARKERS
    block = readme[readme.index(start):readme.index(end)]
    assert len([line for line in block.splitlines() if line.startswith("| ") and "---" not in line]) == len(claims) + 1
    claim = claims[0]  # its first column's difference, recomputed here, is the number the README prints
    payload = json.loads((REPO / "docs/results" / claim.table / f"{claim.file}.json").read_text())
    metric = render.main_metric(payload)
    column = claim.columns[0]
    diff = difference(scores_of(payload["results"][claim.a][column], metric.key),
                      scores_of(payload["results"][claim.b][column], metric.key))
    assert f"{column}: " in block and f"Δ {render.with_interval(diff)}" in block


def test_a_verdict_follows_its_interval():
    readme = (REPO / "README.md").read_text()
    cells = re.findall(r"^\| .*\*\*(.+?)\*\* \|.*$", readme, flags=re.M)
    assert cells
    for cell in cells:  # "holds / tie / holds", or per rival "vs DP2T: holds / tie; vs DPT: ..."
        for per_rival in cell.split("; "):
            assert set(per_rival.split(": ")[-1].split(" / ")) <= {"holds", "tie", "reversed"}, cell


def test_a_changed_json_makes_its_summary_stale(tmp_path, monkeypatch):
    """The drift test can fail: edit one number of a copied table and its summary no longer matches."""
    import shutil

    root = tmp_path / "docs" / "results"
    root.mkdir(parents=True)
    shutil.copytree(REPO / "docs/results/darkroom_ipref", root / "darkroom_ipref")
    shutil.copytree(REPO / "configs", tmp_path / "configs")
    (tmp_path / "README.md").write_text("x\n" + "\n".join(render.README_MARKERS) + "\n")
    (tmp_path / "docs/pretrained.md").write_text("\n".join(render.PRETRAINED_MARKERS) + "\n")
    monkeypatch.chdir(tmp_path)
    keep = {"darkroom_ipref"}
    claims = [c for c in render.read_claims(REPO / "docs/claims.yaml") if c.table in keep]
    (tmp_path / "docs/claims.yaml").write_text(json.dumps([c.__dict__ for c in claims]))
    (root / "darkroom_ipref" / "summary.md").unlink()  # a new table's folder: one render writes it and indexes it
    render.render(root, figures=False)
    assert render.stale(root) == []
    path = root / "darkroom_ipref" / "darkroom_ipref.json"
    payload = json.loads(path.read_text())
    cell = payload["results"]["ICPO"]["low"]
    cell["per_seed"]["normalized_return"][0] += 0.5
    cell["per_task"]["normalized_return"][0] = [v + 0.5 for v in cell["per_task"]["normalized_return"][0]]
    path.write_text(json.dumps(payload))
    stale = {p.name for p in render.stale(root)}
    assert {"summary.md", "RESULTS.md", "README.md"} <= stale


def test_readme_and_package_docstrings_carry_no_history():
    dated = re.compile(r"[Ii]ssue \d+|\b\d{1,2} (January|February|March|April|May|June|July|August|September|"
                       r"October|November|December)\b")
    texts = {"README.md": (REPO / "README.md").read_text()}
    texts.update({str(p.relative_to(REPO)): p.read_text() for p in (REPO / "icprl_lightning").rglob("*.py")})
    assert [name for name, text in texts.items() if dated.search(text)] == []


def test_an_online_bandit_json_renders_its_regret_table():
    from icprl_lightning.evaluation.online_bandit import online_bandit_markdown

    payload = json.loads((REPO / "docs/results/online_bandit/online_bandit_active.json").read_text())
    lines = online_bandit_markdown(payload).splitlines()
    rows = {line.split(" | ")[0].removeprefix("| "): line for line in lines
            if line.startswith("| ") and "---" not in line}
    assert set(rows) == {"row", "DTS", "MaxInP", "BT Thompson sampling",
                         *(f"ICPO ({rule} pairs)" for rule in payload["icpo"])}
    dts = payload["dts"]
    weak = f"{dts['cumulative_weak_regret']:.3g} ± {dts['cumulative_weak_regret_sem']:.2g}"
    assert rows["DTS"].split(" | ")[1] == weak
    assert (REPO / "docs/results/online_bandit/online_bandit_active.md").read_text() == "\n".join(lines) + "\n"
