"""The one stored-data DataModule base: a dataset generated once into ``data/store.py``'s layout, then read.

``PreferenceDataModule`` (a setting's contexts, ``data/datamodule.py``) and ``HistoryWindowDataModule`` (a learner's
histories for AD, ``data/history_windows.py``) share it: the dataset's directory (``data_dir``, or
``<root_dir>/<family>-<store_name>-<hash of the generator config>``), ``prepare_data`` (an existing dataset is
read and checked, a missing one generated under the dataset's lock and written atomically with its manifest, a
read-only dataset read without a lock), ``load`` (the checksums verified once) and ``held_out`` (one error naming
what would serve an evaluation the data does not offer). A subclass says what differs: ``store_name``,
``generator_config``, ``generate``, ``required_fields``, ``regenerate_hint``, the evaluations it ``offers`` and how
it reads them (``_held_out``).
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import Any

import lightning as L
import numpy as np

from icprl_lightning.data.store import (
    StoredDataset,
    check_replaceable_dataset,
    dataset_lock,
    load_dataset,
    write_dataset,
)
from icprl_lightning.data_contract import not_offered


class StoredData(L.LightningDataModule):
    """See the module docstring. A subclass sets ``family``, ``data_dir``, ``root_dir``, ``overwrite``,
    ``verify_checksums``, ``progress`` and ``dataset`` (None) in its ``__init__``."""

    offers: frozenset[str] = frozenset()
    offers_note: str = ""  # said after refusing an evaluation the data does not offer
    generating: str = ""   # what prepare_data announces it generates (with progress on); "" says nothing
    dataset: StoredDataset | None

    # ---- what a subclass defines ---------------------------------------------------------------------
    @property
    def store_name(self) -> str:
        """The dataset directory's middle part."""
        raise NotImplementedError

    @property
    def data_name(self) -> str:
        """The data, as the errors name it."""
        raise NotImplementedError

    def generator_config(self) -> dict[str, Any]:
        """Everything that determines the dataset's bytes (compared against the manifest on load)."""
        raise NotImplementedError

    def generate(self) -> tuple[dict[str, dict[str, np.ndarray]], dict[str, Any]]:
        """The dataset's splits and the manifest's info."""
        raise NotImplementedError

    def required_fields(self) -> dict[str, list[str]]:
        """The arrays, per split, a stored dataset must hold."""
        raise NotImplementedError

    @property
    def regenerate_hint(self) -> str:
        return f"delete {self.path} (or pass --data.init_args.overwrite true); fit generates a missing dataset"

    # ---- storage -------------------------------------------------------------------------------------
    @property
    def path(self) -> Path:
        if self.data_dir is not None:
            return Path(self.data_dir)
        digest = hashlib.sha256(json.dumps(self.generator_config(), sort_keys=True).encode()).hexdigest()[:10]
        return Path(self.root_dir) / f"{self.family.name}-{self.store_name}-{digest}"

    def prepare_data(self) -> None:
        path = self.path
        if not self.overwrite and path.is_dir() and not os.access(path.parent, os.W_OK):
            self._read(verify=False)  # a read-only dataset: nothing to write, no lock to take
            return
        with dataset_lock(path):  # a second process waits here, then finds the dataset made by the first
            if not self.overwrite and (path.exists() or path.is_symlink()):
                self._read(verify=False)
                return
            check_replaceable_dataset(path)  # refuse before generating, not after
            if self.progress and self.generating:
                print(f"generating {self.generating} -> {path}", flush=True)
            splits, info = self.generate()
            write_dataset(path, splits, self.generator_config(), info=info, overwrite=True)
        self.overwrite = False  # generated now; later calls (e.g. setup in another stage) reuse it

    def _read(self, verify: bool) -> StoredDataset:
        data = load_dataset(self.path, self.generator_config(), verify=verify, regenerate_hint=self.regenerate_hint)
        data.require(self.required_fields(), self.regenerate_hint)
        return data

    def load(self) -> StoredDataset:
        if self.dataset is None:
            self.dataset = self._read(verify=self.verify_checksums)
        return self.dataset

    # ---- the held-out evaluations -------------------------------------------------------------------
    def held_out(self, evaluation: str) -> Any:
        """What an offered evaluation reads (``data_contract.PreferenceData.held_out``); a subclass that offers
        one reads it in ``_held_out``."""
        if evaluation not in self.offers:
            raise not_offered(self.data_name, evaluation, self.offers, self.offers_note)
        return self._held_out(evaluation)

    def _held_out(self, evaluation: str) -> Any:
        raise NotImplementedError
