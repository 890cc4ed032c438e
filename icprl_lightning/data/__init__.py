"""Datasets: settings (recipes), the store, batches, and the DataModules of generated and recorded data.

``PreferenceDataModule`` (a Lightning DataModule) is imported on first use (PEP 562), so the commands that only
read or write stored data (``icprl import``, ``export-data``) never import Lightning.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from icprl_lightning.data.datamodule import PreferenceDataModule

__all__ = ["PreferenceDataModule"]


def __getattr__(name: str) -> Any:
    if name == "PreferenceDataModule":
        from icprl_lightning.data.datamodule import PreferenceDataModule

        return PreferenceDataModule
    raise AttributeError(f"module 'icprl_lightning.data' has no attribute {name!r}")
