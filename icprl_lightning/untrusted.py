"""Reading a file someone else may have written: bounded before anything is allocated, one error naming the file.

* ``read_json`` / ``read_yaml`` / ``parse_json``: the one reader of every JSON and YAML file a command is handed
  (model ``config.json``, export provenance, experiment files and overlays, fit records, run configs, result
  files, manifests). The file must be a regular file (a FIFO would block forever, a device never ends) of at most
  ``MAX_TEXT_BYTES``; the value may nest at most ``MAX_DEPTH`` deep and hold at most ``MAX_VALUES`` values,
  counted with YAML aliases expanded (a "billion laughs" file is a few lines). Anything else — unreadable,
  not UTF-8, not JSON/YAML, too deep for the parser (``RecursionError``) — is one ``UntrustedFileError``
  naming the file.
* ``check_torch_archive``: a ``torch.save`` file is a zip archive whose members ``torch.load`` reads into memory
  whole, inflating a compressed one first (a 344 KB file can declare 805 MB). Before ``torch.load`` sees a file,
  its central directory is read (names and sizes, no data) and every member must be stored uncompressed, as
  ``torch.save`` writes them (so what is read is at most what the file holds), lie inside the file, and the
  whole stay within ``MAX_CHECKPOINT_BYTES``. A file that is not a zip archive is refused too: the legacy
  (pre-1.6) torch format allocates each storage at the size its pickle declares.
"""

from __future__ import annotations

import io
import json
import math
import os
import stat
import types
import typing
import zipfile
from pathlib import Path
from typing import Any

from icprl_lightning.io import file_kind

MAX_TEXT_BYTES = 64 << 20  # a JSON or YAML file
MAX_DEPTH = 64  # nesting of lists and mappings; our files nest at most ~8
MAX_VALUES = 2_000_000  # values in one file, YAML aliases expanded
MAX_CHECKPOINT_BYTES = 8 << 30  # a checkpoint, or a member of one, read into memory whole


class UntrustedFileError(ValueError):
    """A file refused before or while it was parsed; the message names it and what was wrong."""


def regular_file_size(path: str | Path, what: str, max_bytes: int) -> int:
    """``path``'s size, after checking it is a regular file (not a FIFO, device, socket or directory) of at
    most ``max_bytes``; a missing file is ``FileNotFoundError``, anything else an ``UntrustedFileError``."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise FileNotFoundError(f"no such file: {path}") from None
    except OSError as e:
        raise UntrustedFileError(f"{path}: cannot read it ({e.strerror or e})") from None
    if not stat.S_ISREG(st.st_mode):
        raise UntrustedFileError(f"{path} is {file_kind(st.st_mode)}, not a regular file; expected {what}")
    if st.st_size > max_bytes:
        raise UntrustedFileError(f"{path} is {st.st_size:,} bytes, more than the {max_bytes:,} a {what} may hold")
    return st.st_size


def _read_text(path: str | Path, what: str, max_bytes: int) -> str:
    regular_file_size(path, what, max_bytes)
    try:
        with open(path, "rb") as f:
            data = f.read(max_bytes + 1)  # the file may have grown since stat
    except OSError as e:
        raise UntrustedFileError(f"{path}: cannot read it ({e.strerror or e})") from None
    if len(data) > max_bytes:
        raise UntrustedFileError(f"{path} is more than the {max_bytes:,} bytes a {what} may hold")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as e:
        raise UntrustedFileError(f"{path} is not UTF-8 text ({e.reason} at byte {e.start}); expected {what}") from None


def check_shape(value: Any, where: str, max_depth: int = MAX_DEPTH, max_values: int = MAX_VALUES) -> Any:
    """``value`` after checking, without recursion, that it nests at most ``max_depth`` deep and holds at most
    ``max_values`` values (a value reached twice, as YAML aliases are, counts twice)."""
    stack, count = [(value, 1)], 0
    while stack:
        node, depth = stack.pop()
        count += 1
        if count > max_values:
            raise UntrustedFileError(f"{where} holds more than {max_values:,} values (YAML aliases expanding?); "
                                     "refusing to read it")
        if isinstance(node, dict | list | tuple):
            if depth > max_depth:
                raise UntrustedFileError(f"{where} nests deeper than {max_depth} levels; refusing to read it")
            children = [*node.keys(), *node.values()] if isinstance(node, dict) else node
            stack.extend((child, depth + 1) for child in children)
    return value


def parse_json(text: str | bytes, where: str, max_bytes: int = MAX_TEXT_BYTES) -> Any:
    """JSON ``text`` (from ``where``, which messages name), bounded as the module docstring says."""
    if len(text) > max_bytes:
        raise UntrustedFileError(f"{where} is {len(text):,} bytes, more than the {max_bytes:,} allowed for JSON")
    try:
        value = json.loads(text)
    except RecursionError:
        raise UntrustedFileError(f"{where} nests deeper than {MAX_DEPTH} levels; refusing to read it") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise UntrustedFileError(f"{where} is not valid JSON ({e})") from None
    return check_shape(value, where)


def read_json(path: str | Path, what: str = "JSON file", max_bytes: int = MAX_TEXT_BYTES) -> Any:
    """The JSON value in ``path`` (``what`` names the kind in messages), bounded as the module docstring says."""
    return parse_json(_read_text(path, what, max_bytes), str(path), max_bytes)


def read_yaml(path: str | Path, what: str = "YAML file", max_bytes: int = MAX_TEXT_BYTES) -> Any:
    """``yaml.safe_load`` of ``path`` (plain values only), bounded as the module docstring says."""
    import yaml

    text = _read_text(path, what, max_bytes)
    try:
        value = yaml.safe_load(text)
    except RecursionError:
        raise UntrustedFileError(f"{path} nests deeper than {MAX_DEPTH} levels; refusing to read it") from None
    except yaml.YAMLError as e:
        raise UntrustedFileError(f"{path} is not valid YAML ({' '.join(str(e).split())})") from None
    return check_shape(value, str(path))


def check_torch_archive(source: str | Path | bytes, where: str | None = None,
                        max_bytes: int = MAX_CHECKPOINT_BYTES) -> None:
    """Refuse a ``torch.save`` file (a path, or its bytes) that ``torch.load`` would inflate or read beyond its
    own size (module docstring), with an ``UntrustedFileError`` naming ``where`` (default: the path)."""
    where = where or str(source)
    if isinstance(source, bytes):
        size, opened = len(source), io.BytesIO(source)
    else:
        size, opened = regular_file_size(source, "torch file", max_bytes), source
    if size > max_bytes:
        raise UntrustedFileError(f"{where} is {size:,} bytes, more than the {max_bytes:,} a torch file may hold")
    damaged = f"{where} is not a readable checkpoint: damaged, truncated or not a torch file"
    try:
        with zipfile.ZipFile(opened) as archive:  # the central directory only: names and sizes
            members = archive.infolist()
    except zipfile.BadZipFile:
        raise UntrustedFileError(f"{damaged} (no zip archive; torch.save writes one since torch 1.6, and the "
                                 "older format is refused)") from None
    except (OSError, ValueError, EOFError, UnicodeDecodeError, zipfile.LargeZipFile) as e:
        raise UntrustedFileError(f"{damaged} ({type(e).__name__}: {e})") from None
    total = 0
    for m in members:
        if m.compress_type != zipfile.ZIP_STORED or m.compress_size != m.file_size:
            raise UntrustedFileError(f"{where}: member {m.filename!r} is compressed ({m.compress_size:,} bytes "
                                     f"declaring {m.file_size:,}); torch.save never compresses, and torch.load would "
                                     "inflate it in memory before any check; refusing to load it")
        total += m.file_size
        if m.header_offset + m.compress_size > size or total > size:
            raise UntrustedFileError(f"{where}: member {m.filename!r} declares {m.file_size:,} bytes, beyond the "
                                     f"file's {size:,}: truncated or forged")


def check_argument_types(cls: type, arguments: dict[str, Any], where: str) -> None:
    """Refuse an argument of ``cls.__init__`` annotated ``bool``, ``int`` or ``float`` (or ``X | None``) whose
    value in ``arguments`` (read from a file) is not of that type: a string "false" would build a discrete model,
    a float where an integer is expected fails deep inside torch, a NaN passes ``x > 0`` unnoticed."""
    try:
        hints = typing.get_type_hints(cls.__init__)
    except (NameError, TypeError):  # an annotation this module cannot resolve: the constructor's own checks remain
        return
    for key, value in arguments.items():
        hint = hints.get(key)
        allowed = typing.get_args(hint) if typing.get_origin(hint) in (typing.Union, types.UnionType) else (hint,)
        if value is None and type(None) in allowed:
            continue
        if bool in allowed:
            ok, kind = isinstance(value, bool), "true or false"
        elif int in allowed:
            ok, kind = isinstance(value, int) and not isinstance(value, bool), "an integer"
        elif float in allowed:
            ok = isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
            kind = "a finite number"
        else:
            continue
        if not ok:
            raise UntrustedFileError(f"{where}: hyperparameter {key!r} of {cls.__name__} must be {kind}, got "
                                     f"{value!r}")
