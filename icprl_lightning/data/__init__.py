"""Datasets: settings (recipes), the store, batches, and the DataModules of generated and recorded data."""

from icprl_lightning.data.datamodule import PreferenceDataModule

__all__ = ["PreferenceDataModule"]
