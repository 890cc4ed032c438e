"""Datasets that travel: our store's datasets in Hugging Face, Parquet and Minari form, and foreign preference rows.

* ``hf.py``: a dataset as a ``datasets.DatasetDict`` saved to disk (Arrow), or as Parquet files.
* ``minari_format.py``: reward contexts as Minari episodes (other kinds are refused, naming the formats that fit).
* ``provenance.py``: the manifest each export carries, and the byte-for-value check that rebuilds the dataset.
* ``preference_rows.py``: TRL chosen/rejected rows and imitation/B-Pref segment-pair label arrays as contexts.
* ``icprl export-data`` (``commands/export_data.py``) writes them; ``icprl import --format`` (``data/importer.py``)
  reads them back.

``docs/data_formats.md`` maps every field of every format.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from icprl_lightning.data.interop.hf import export_hf, export_parquet, import_hf, import_parquet
from icprl_lightning.data.interop.minari_format import export_minari, import_minari
from icprl_lightning.data.interop.provenance import ExportError
from icprl_lightning.data.store import StoredDataset, load_dataset

EXPORTERS: dict[str, Callable[[StoredDataset, str | Path], Path]] = {
    "hf": export_hf, "parquet": export_parquet, "minari": export_minari}
IMPORTERS: dict[str, Callable[..., Path]] = {"hf": import_hf, "parquet": import_parquet, "minari": import_minari}

__all__ = ["EXPORTERS", "IMPORTERS", "ExportError", "export_dataset", "import_export"]


def export_dataset(dataset: str | Path, fmt: str, out: str | Path) -> Path:
    """Write the dataset at ``dataset`` (checked against its manifest's checksums) as ``fmt`` at ``out``."""
    if fmt not in EXPORTERS:
        raise ValueError(f"format must be one of {sorted(EXPORTERS)}, got {fmt!r}")
    return EXPORTERS[fmt](load_dataset(dataset, verify=True), out)


def import_export(fmt: str, source: str | Path, out: str | Path, overwrite: bool = False) -> Path:
    """Rebuild, at ``out``, the dataset an ``fmt`` export at ``source`` came from; the same bytes or ``ExportError``."""
    if fmt not in IMPORTERS:
        raise ValueError(f"format must be one of {sorted(IMPORTERS)}, got {fmt!r}")
    return IMPORTERS[fmt](source, out, overwrite=overwrite)
