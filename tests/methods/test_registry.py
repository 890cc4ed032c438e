"""The method registry (registry.py): a user's method is a peer of the built-in ones once registered, and a file
never makes the package import code — a name that is not registered is refused before anything is imported.

docs/extending_methods.md takes a method defined outside the package through every command (fit, export,
load_agent, evaluate, reproduce); here the registry's own promises, each with the case that would break it.
"""

from __future__ import annotations

import sys

import pytest
import torch
import torch.nn.functional as F
from factories import save_untrained

from icprl_lightning import StepPreferenceContext, load_agent, register_method
from icprl_lightning.checkpoints import CLASS_KEY, checksum, seal
from icprl_lightning.methods.base import InContextModule
from icprl_lightning.models.config import OptimizerConfig
from icprl_lightning.registry import BUILTIN_METHODS, ENTRY_POINT_GROUP, METHODS, method_class, method_names

TOY_OPTIMIZER = OptimizerConfig(lr=1e-3)


class ArgmaxOfPreferred(InContextModule):
    """A test's own method: cross-entropy toward the preferred action of the context's own comparisons."""

    def __init__(self, state_dim: int, action_dim: int, discrete: bool, max_context: int, *,
                 optimizer: OptimizerConfig = TOY_OPTIMIZER):
        super().__init__("step_preference", state_dim, action_dim, discrete, max_context,
                         backbone={"n_layer": 1, "n_embd": 16, "n_head": 2}, optimizer=optimizer)

    def loss(self, batch):
        c = batch.context
        t = c.states.shape[1]
        logits = self.policy(c, c.states, torch.full((t,), t))
        return F.cross_entropy(logits.flatten(0, 1), c.actions.flatten()), {}


@pytest.fixture
def registered():
    """ArgmaxOfPreferred registered for one test, then forgotten."""
    register_method(ArgmaxOfPreferred)
    yield ArgmaxOfPreferred
    METHODS.forget(f"{__name__}.ArgmaxOfPreferred")


def _context(b: int = 2, t: int = 5) -> StepPreferenceContext:
    g = torch.Generator().manual_seed(0)
    return StepPreferenceContext(torch.rand(b, t, 2, generator=g), torch.randint(0, 5, (b, t), generator=g),
                                 torch.randint(0, 5, (b, t), generator=g), torch.ones(b, t))


def test_a_registered_method_saves_and_deploys_through_load_agent(registered, tmp_path):
    path = save_untrained(registered(state_dim=2, action_dim=5, discrete=True, max_context=5), tmp_path / "m.ckpt")
    agent = load_agent(path)
    agent.reset(_context())
    assert agent.act(torch.rand(2, 2)).shape == (2,)
    assert torch.load(path, weights_only=True)[CLASS_KEY] == f"{__name__}.ArgmaxOfPreferred"


def test_the_same_file_is_refused_once_the_method_is_not_registered(registered, tmp_path):
    path = save_untrained(registered(state_dim=2, action_dim=5, discrete=True, max_context=5), tmp_path / "m.ckpt")
    METHODS.forget(f"{__name__}.ArgmaxOfPreferred")
    with pytest.raises(ValueError, match="ArgmaxOfPreferred', which is not a registered method .*refusing to "
                                         "import it"):
        load_agent(path)


def test_a_name_that_is_not_registered_is_never_imported(tmp_path, monkeypatch):
    """A file naming an importable module's class: refused by name, and the module's code never runs."""
    (tmp_path / "planted.py").write_text("import pathlib\npathlib.Path(__file__).with_name('ran').touch()\n"
                                         "class Payload:\n    pass\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    with pytest.raises(ValueError, match="'planted.Payload' is not a registered method"):
        method_class("planted.Payload")
    good = ArgmaxOfPreferred(state_dim=2, action_dim=5, discrete=True, max_context=5)
    path = save_untrained(good, tmp_path / "m.ckpt")
    ckpt = torch.load(path, weights_only=True)
    ckpt[CLASS_KEY] = "planted.Payload"  # a forged file, its checksum and seal made consistent
    ckpt["icprl_sha256"] = checksum("planted.Payload", ckpt["hyper_parameters"], ckpt["state_dict"])
    ckpt["icprl_seal"] = seal(ckpt)
    torch.save(ckpt, path)
    with pytest.raises(ValueError, match="not a registered method"):
        load_agent(path)
    assert "planted" not in sys.modules and not (tmp_path / "ran").exists()


def _install(tmp_path, monkeypatch, value: str) -> None:
    """An entry point of group icprl_lightning.methods, as an installed package's metadata declares it."""
    dist = tmp_path / "toy_methods-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: toy-methods\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text(f"[{ENTRY_POINT_GROUP}]\ntoy = {value}\n")
    (tmp_path / "toy_methods.py").write_text(f"from {__name__} import ArgmaxOfPreferred as Imported\n"
                                             "class Other:\n    pass\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.delitem(sys.modules, "toy_methods", raising=False)


def test_an_installed_entry_point_is_registered_without_being_imported(tmp_path, monkeypatch):
    _install(tmp_path, monkeypatch, "toy_methods:Other")
    assert method_names()[:len(BUILTIN_METHODS)] == BUILTIN_METHODS
    assert "toy_methods.Other" in method_names() and "toy_methods" not in sys.modules
    assert method_class("toy_methods.Other").__name__ == "Other"


def test_an_entry_point_whose_object_is_not_the_class_it_names_is_refused(tmp_path, monkeypatch):
    """``toy_methods:Imported`` names toy_methods.Imported, but loads a class defined elsewhere."""
    _install(tmp_path, monkeypatch, "toy_methods:Imported")
    with pytest.raises(ValueError, match="loads .*ArgmaxOfPreferred.*not the class it names"):
        method_class("toy_methods.Imported")


@pytest.mark.parametrize("thing", [len, "icprl_lightning.methods.icpo.ICPOModule", torch.nn.Linear])
def test_register_method_takes_only_a_method_class(thing):
    with pytest.raises(TypeError, match="register_method"):
        register_method(thing)
