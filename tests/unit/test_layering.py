"""The package's layers (DESIGN.md, "Layers"), checked by reading every module's imports.

Each module may import only from its own layer or the layers below it. And the structural half of
"reward-free means reward-free": nothing under ``models/`` or ``methods/`` (nor ``deploy.py``, which they
use) imports a family, an oracle, an annotator, a setting (generator) or any dataset code — so no path exists by which
a model could be handed a goal, a reward of the simulator or A*.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[2] / "icprl_lightning"

# lowest first; a module's layer is the first entry its dotted name starts with
LAYERS = [
    ("contexts", "preferences", "io", "metrics", "validation",   # ground: shared vocabulary, argument checks,
     "progress"),                                                 # progress lines
    ("families",),                                  # task families, their envs and oracles
    ("annotators",),                                # who labels a pair (sees the oracle's utilities)
    ("data",),                                      # settings (generators), store, DataModules
    ("models",),                                    # plain nn.Modules
    ("deploy", "checkpoints", "online"),            # Agent / load_agent; safe checkpoint files (methods by an
                                                    # allow-list of names, imported by importlib, not statically)
    ("methods",),                                   # LightningModules
    ("evaluation",),                                # rollouts and duels through the Agent
    ("callbacks",),
    ("baselines",),                                 # SB3 from scratch
    ("cli", "trainer_cli", "reproduce", "__init__"),  # the commands (reproduce runs `icprl fit` and `evaluate`)
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
