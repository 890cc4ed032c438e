"""The generated docs equal a fresh render of the results JSON: no number in them can drift from its data."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
from factories import REPO

from icprl_lightning.reproduce import render
from icprl_lightning.reproduce.claims import Comparison, read_claims, signed
from icprl_lightning.reproduce.statistics import Scores, difference, scores_of


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


def claims_block() -> str:
    readme = (REPO / "README.md").read_text()
    start, end = render.README_MARKERS
    return readme[readme.index(start):readme.index(end)]


def test_the_claims_table_has_one_short_row_per_claim_each_read_from_its_json():
    claims = read_claims()
    assert 0 < len(claims) <= 14
    block = claims_block()
    rows = [line for line in block.splitlines() if line.startswith("| ") and "---" not in line]
    headers = [row for row in rows if row.startswith("| the paper's claim |")]
    assert len(rows) - len(headers) == len(claims) and 1 <= len(headers) <= 2
    for row in rows[1:]:  # every verdict cell, bold markers aside, is at most ~40 characters
        cells = [c.strip() for c in row.strip("|").split(" | ")]
        assert all(len(c.replace("**", "")) <= 40 for c in cells[2:-1] if c.startswith("**")), row
    claim = claims[0]  # its first column's difference, recomputed here, is the number the README prints
    payload = json.loads((REPO / "docs/results" / claim.table / f"{claim.file}.json").read_text())
    metric = render.main_metric(payload)
    diff = difference(scores_of(payload["results"][claim.a][claim.columns[0]], metric.key),
                      scores_of(payload["results"][claim.b][claim.columns[0]], metric.key))
    assert f"{signed(diff.point)} [{signed(diff.low)}, {signed(diff.high)}]" in block


def test_no_internal_run_name_reaches_the_claims_table():
    block = claims_block()
    internal = {row for claim in read_claims() for row in (claim.a, claim.b)
                if re.search(r"[_@\d]", row) or row in ("dts", "maxinp")}  # DP2T, b1_l0.25, ICPO@flipped_labels
    assert internal and [row for row in internal if re.search(rf"\b{re.escape(row)}\b", block)] == []


def test_a_verdict_follows_its_interval_or_counts_the_seeds():
    cells = re.findall(r"\*\*(.+?)\*\* ([^|]+)", claims_block())
    assert cells
    for word, numbers in cells:
        if word in ("holds", "tie", "reversed"):  # an interval over seeds × tasks
            assert re.fullmatch(r"[+-]\d\.\d{3} \[[+-]\d\.\d{3}, [+-]\d\.\d{3}\] ", numbers), numbers
        else:  # seed means only: no interval, each seed's difference
            assert re.fullmatch(r"\d of 3 seeds", word) and re.fullmatch(r"([+-]\d\.\d{3} ){3}", numbers), word


def test_a_seed_only_claim_counts_its_seeds_and_draws_no_interval():
    a = Scores(np.array([[0.5], [0.2], [0.7]]), tasks_recorded=False)
    b = Scores(np.array([[0.4]]), tasks_recorded=False)
    c = Comparison("low", a, b, True, "here")
    assert c.cell() == "**2 of 3 seeds** +0.100 -0.200 +0.300"
    assert Comparison("low", a, b, False, "here").verdict() == "1 of 3 seeds"  # regret: lower is better
    with_tasks = Comparison("low", Scores(np.array([[0.5, 0.6]] * 3), True), Scores(np.array([[0.1, 0.2]] * 3), True),
                            True, "here")
    assert with_tasks.cell() == "**holds** +0.400 [+0.400, +0.400]"


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
    claims = [c for c in read_claims(REPO / "docs/claims.yaml") if c.table in keep]
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
