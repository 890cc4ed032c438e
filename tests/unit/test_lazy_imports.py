"""``import icprl_lightning`` (and so ``icprl --help``) does not import torch: the package's public names are
imported on first use (``icprl_lightning/__init__.py``), and each still resolves to its defining module."""

from __future__ import annotations

import subprocess
import sys

import pytest

import icprl_lightning


def _imports_torch(statement: str) -> bool:
    code = f"import sys\n{statement}\nprint('torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True)
    return out.stdout.strip() == "True"


def test_importing_the_package_does_not_import_torch():
    assert not _imports_torch("import icprl_lightning")


def test_a_public_name_imports_its_module_on_first_use():
    assert _imports_torch("from icprl_lightning import load_agent")


@pytest.mark.parametrize("name", icprl_lightning.__all__)
def test_every_public_name_resolves_to_its_module(name):
    value = getattr(icprl_lightning, name)
    assert value.__module__ == icprl_lightning._EXPORTS[name] and name in dir(icprl_lightning)


def test_the_exports_are_the_public_names():
    assert sorted(icprl_lightning.__all__) == sorted(icprl_lightning._EXPORTS)


def test_an_unknown_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="has no attribute 'load_agnet'"):
        icprl_lightning.load_agnet  # noqa: B018


@pytest.mark.parametrize("group", ["oracle", "baseline", "analyze"])
def test_a_group_lists_its_verbs_without_importing_torch(group):
    """``icprl oracle --help`` (and every group's) answers from ``cli.GROUPS`` alone, as ``icprl --help`` does."""
    code = (f"import sys; from icprl_lightning.commands import main; main([{group!r}, '--help']); "
            "print('torch' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True).stdout
    lines = out.splitlines()
    assert lines[-1] == "False", out
    from icprl_lightning.commands import GROUPS

    for verb in GROUPS[group]:
        assert any(line.startswith(f"  {verb} ") for line in lines), (verb, out)
