"""The package's layers (DESIGN.md, "Layers"), checked by reading every module's imports.

Each module may import only from its own layer or the layers below it. And the structural half of
"reward-free means reward-free": nothing under ``models/`` or ``methods/`` (nor ``deploy.py``, which they
use) imports a family, an oracle, an annotator, a setting (generator) or any dataset code — so no path exists by which
a model could be handed a goal, a reward of the simulator or A*.

Outside the package, ``experiments/`` holds one-off investigations: neither the package nor the tests import
them (nor a ``scripts/`` directory), or put either directory on ``sys.path`` to import its files by name.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
PACKAGE = REPO / "icprl_lightning"

# lowest first; a module's layer is the first entry its dotted name starts with
LAYERS = [
    ("contexts", "preferences", "io", "untrusted", "metrics", "validation",  # ground: shared vocabulary, checks,
     "progress", "data_contract", "samples", "registry"),         # progress lines, what a DataModule serves,
                                                                  # typed training samples, the registries
    ("sb3",),                                       # SB3 agents evaluated while they train (oracle, baselines)
    ("families",),                                  # task families, their envs and oracles
    ("annotators",),                                # who labels a pair (sees the oracle's utilities)
    ("data",),                                      # settings (generators), store, DataModules
    ("models",),                                    # plain nn.Modules
    ("deploy", "checkpoints", "online", "hub"),     # Agent / load_agent; safe checkpoint files (methods by the
                                                    # registry's names, imported only when registered)
    ("methods",),                                   # LightningModules
    ("labelling",),                                 # the labelling page's server, answer log, export, online page
    ("evaluation",),                                # rollouts and duels through the Agent
    ("callbacks",),
    ("baselines",),                                 # SB3 from scratch
    ("commands", "reproduce", "__init__",           # the commands room (reproduce runs `icprl fit` and `evaluate`),
     "__main__"),                                   # and `python -m icprl_lightning`, the same front door
]
REWARD_FREE = ("models", "methods", "deploy", "online")
FORBIDDEN_FOR_REWARD_FREE = ("families", "annotators", "data")


def _layer(module: str) -> int:
    first = module.split(".")[0]
    for rank, names in enumerate(LAYERS):
        if first in names:
            return rank
    raise AssertionError(f"icprl_lightning.{module} is in no layer: add it to LAYERS")


def _modules() -> list[tuple[str, Path]]:
    out = []
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(PACKAGE).with_suffix("")
        parts = rel.parts[:-1] if rel.name == "__init__" and len(rel.parts) > 1 else rel.parts
        out.append((".".join(parts), path))
    return out


def _imports(path: Path) -> set[str]:
    """The icprl_lightning modules a file imports statically (at any depth, lazy imports included)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("icprl_lightning"):
            found.add(node.module.removeprefix("icprl_lightning").lstrip("."))
        elif isinstance(node, ast.Import):
            found |= {a.name.removeprefix("icprl_lightning.") for a in node.names
                      if a.name.startswith("icprl_lightning.")}
    return {m for m in found if m}


MODULES = _modules()


def test_every_module_belongs_to_a_layer():
    assert len(MODULES) > 40
    for module, _ in MODULES:
        _layer(module)


@pytest.mark.parametrize(("module", "path"), MODULES, ids=[m for m, _ in MODULES])
def test_no_module_imports_a_higher_layer(module, path):
    own = _layer(module)
    higher = sorted(dep for dep in _imports(path) if _layer(dep) > own)
    assert not higher, f"icprl_lightning.{module} (layer {own}) imports higher layers: {higher}"


def _command_parts(path: Path) -> list[str]:
    """What makes a file a command: a top-level ``main``, an ``if __name__ == "__main__"`` block, argparse."""
    tree = ast.parse(path.read_text())
    found = [f"def {n.name}" for n in tree.body if isinstance(n, ast.FunctionDef) and n.name == "main"]
    found += ["__main__ block" for n in tree.body if isinstance(n, ast.If) and "__main__" in ast.unparse(n.test)]
    found += ["import argparse" for n in ast.walk(tree) if isinstance(n, ast.Import | ast.ImportFrom)
              and "argparse" in ([a.name for a in n.names] if isinstance(n, ast.Import) else [n.module])]
    return found


@pytest.mark.parametrize(("module", "path"), [(m, p) for m, p in MODULES if not m.startswith("commands")],
                         ids=[m for m, _ in MODULES if not m.startswith("commands")])
def test_library_modules_hold_no_command(module, path):
    """Every program lives in icprl_lightning/commands/ behind `icprl`: no main(), no `python -m` back door, no
    argparse in a library module."""
    assert not _command_parts(path), f"icprl_lightning.{module} holds {_command_parts(path)}: commands/ holds these"


def test_the_command_check_sees_main_back_doors_and_argparse(tmp_path):
    probe = tmp_path / "probe.py"
    probe.write_text("def f():\n    import argparse\n\ndef main():\n    pass\n\nif __name__ == '__main__':\n"
                     "    main()\n")
    assert _command_parts(probe) == ["def main", "__main__ block", "import argparse"]


@pytest.mark.parametrize(("module", "path"), [(m, p) for m, p in MODULES if m.split(".")[0] in REWARD_FREE],
                         ids=[m for m, _ in MODULES if m.split(".")[0] in REWARD_FREE])
def test_models_and_methods_never_import_families_oracles_or_generators(module, path):
    bad = sorted(dep for dep in _imports(path) if dep.split(".")[0] in FORBIDDEN_FOR_REWARD_FREE)
    assert not bad, f"icprl_lightning.{module} imports {bad}: a learner must not reach goals, rewards or A*"


def test_the_check_sees_lazy_imports(tmp_path):
    """A function-level import counts: the check cannot be dodged by importing inside a method."""
    probe = tmp_path / "probe.py"
    probe.write_text("def f():\n    from icprl_lightning.families.darkroom import oracle\n    return oracle\n")
    assert _imports(probe) == {"families.darkroom"}


OUTSIDE = ("experiments", "scripts")  # never imported by the package or the tests
PATH_CALLS = {"insert", "append", "extend", "syspath_prepend"}  # sys.path.insert(...), monkeypatch.syspath_prepend


def _investigations() -> set[str]:
    """The module names a file of ``experiments/`` or ``scripts/`` would be imported by, once on ``sys.path``."""
    return {p.stem for d in OUTSIDE for p in (REPO / d).glob("*.py")}


def _outside_uses(path: Path, names: set[str]) -> list[str]:
    """Imports of ``experiments``/``scripts`` (as packages, or their files by name) and sys.path edits naming them."""
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            modules = [node.module]
        elif isinstance(node, ast.Import):
            modules = [a.name for a in node.names]
        else:
            modules = []
        found += [f"line {node.lineno}: import {m}" for m in modules
                  if m.split(".")[0] in OUTSIDE or m.split(".")[0] in names]
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr in PATH_CALLS:
            strings = [c.value for arg in node.args for c in ast.walk(arg)
                       if isinstance(c, ast.Constant) and isinstance(c.value, str)]
            if any(re.search(rf"(^|/)({'|'.join(OUTSIDE)})(/|$)", v) for v in strings):
                found.append(f"line {node.lineno}: {node.func.attr}({', '.join(map(repr, strings))})")
    return sorted(found, key=lambda hit: int(hit.split(":")[0].removeprefix("line ")))


SOURCES = sorted([*PACKAGE.rglob("*.py"), *(REPO / "tests").rglob("*.py")])


@pytest.mark.parametrize("path", SOURCES, ids=[str(p.relative_to(REPO)) for p in SOURCES])
def test_neither_the_package_nor_the_tests_reach_experiments_or_scripts(path):
    # a test module named like an investigation would be a false hit: only names that are not the package's own
    names = _investigations() - {p.stem for p in PACKAGE.rglob("*.py")}
    assert not _outside_uses(path, names), f"{path.relative_to(REPO)} reaches {'/ or '.join(OUTSIDE)}/: " \
        f"{_outside_uses(path, names)}"


def test_the_outside_check_sees_imports_and_sys_path_edits(tmp_path):
    probe = tmp_path / "probe.py"
    probe.write_text("import sys\nfrom pathlib import Path\n"
                     "sys.path.insert(0, str(Path(__file__).parents[2] / 'scripts'))\n"
                     "import reach_probe\nfrom experiments.x import y\nmonkeypatch.syspath_prepend('experiments')\n")
    assert _outside_uses(probe, {"reach_probe"}) == [
        "line 3: insert('scripts')", "line 4: import reach_probe", "line 5: import experiments.x",
        "line 6: syspath_prepend('experiments')"]
    probe.write_text("import json\nfrom icprl_lightning.evaluation import online_mdp\nsys.path.insert(0, 'src')\n")
    assert _outside_uses(probe, {"reach_probe"}) == []


def test_experiments_are_headed_by_question_date_and_answer():
    for path in sorted((REPO / "experiments").glob("*.py")):
        doc = ast.get_docstring(ast.parse(path.read_text())) or ""
        assert re.match(r"Question: .+\n\nAsked: \d{4}-\d{2}-\d{2}", doc, re.S), path.name
        assert "\nAnswer (" in doc, path.name
    assert not (REPO / "scripts").exists(), "scripts/ is gone: one-off investigations live in experiments/"
