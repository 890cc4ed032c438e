"""Reading a user's ``.npz`` file or directory of ``.npy`` files safely: nothing is allocated before it is checked.

The source of ``icprl import`` is untrusted, and a ``.npy`` header may declare anything: a shape of 10^12
elements in a 1 KB file (a memory bomb, made worse by an ``.npz``'s compression), an object dtype (which
would need unpickling), a length the file does not hold (truncated). So every header is read first with
``numpy.lib.format`` (shape and dtype, without the data), and

* the dtype must be plain numbers (bool, integer, float; no objects, records or sub-arrays);
* the declared data (elements x item size) must fit in what the file holds after its header (for an
  ``.npz`` member, its uncompressed size);
* the declared data of all arrays together must stay within ``max_bytes`` (``MAX_SOURCE_BYTES``, 8 GiB
  by default: the importer holds the arrays in memory, converted, so its peak is a small multiple of it).

Only then are the arrays read. Anything wrong — a forged or truncated header, a corrupt archive or
compressed stream, a member that is not an ``.npy`` — is one ``ValueError`` naming the file (and the
member of an ``.npz``); an operating-system error is one ``io.StorageError`` naming the file.
"""

from __future__ import annotations

import math
import zipfile
import zlib
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import IO, Any

import numpy as np

from icprl_lightning.io import storage_error
from icprl_lightning.untrusted import UntrustedFileError, regular_file_size

MAX_SOURCE_BYTES = 8 << 30  # declared bytes of all source arrays together (they are loaded into memory)
Opener = Callable[[], IO[bytes]]


def read_source(source: str | Path, max_bytes: int = MAX_SOURCE_BYTES) -> dict[str, np.ndarray]:
    """The arrays of an ``.npz`` file or of a directory's ``*.npy`` files, loaded without unpickling.

    Every header is checked (``_declared``) before any array is read, so a forged shape allocates nothing.
    """
    path = Path(source)
    if not path.exists():
        raise FileNotFoundError(f"no such file or directory: {path}")
    if path.is_dir():
        files = sorted(path.glob("*.npy"))
        if not files:
            raise ValueError(f"{path} holds no .npy files; expected one <field>.npy per field")
        opened = {p.stem: (str(p), partial(p.open, "rb"), _size(p)) for p in files}
        return _read_all(opened, max_bytes)
    if path.suffix != ".npz":
        raise ValueError(f"{path} is neither an .npz file nor a directory of .npy files")
    try:
        archive = zipfile.ZipFile(path)  # reads the central directory (names and sizes), no member data
    except OSError as e:
        raise storage_error(e, path, "reading") from None
    except (zipfile.BadZipFile, zipfile.LargeZipFile, ValueError, EOFError, UnicodeDecodeError) as e:
        raise ValueError(f"{path}: not a readable .npz archive, truncated or corrupt ({_one_line(e)})") from None
    with archive:
        members = archive.infolist()
        bad = [m.filename for m in members if not m.filename.endswith(".npy") or m.is_dir()]
        if bad:
            raise ValueError(f"{path}: member {bad[0]!r} is not an .npy array; save the arrays with np.savez")
        opened = {m.filename.removesuffix(".npy"): (f"{path} (member {m.filename!r})", partial(archive.open, m),
                                                    m.file_size) for m in members}
        return _read_all(opened, max_bytes)


def _size(path: Path) -> int:
    """The size of a regular file (a FIFO named like a field would block the reader forever)."""
    try:
        return regular_file_size(path, ".npy array", 1 << 62)
    except UntrustedFileError as e:
        raise ValueError(str(e)) from None
    except OSError as e:
        raise storage_error(e, path, "reading") from None


def _one_line(e: BaseException) -> str:
    return " ".join(str(e).split())[:300] or type(e).__name__


def _read_all(opened: dict[str, tuple[str, Opener, int]], max_bytes: int) -> dict[str, np.ndarray]:
    """Check every header (shape, dtype, size; and the total against ``max_bytes``), then read the arrays.

    ``opened`` maps a field to (its name in messages, a function opening it, its size in bytes).
    """
    total, declared = 0, {}
    for name, (where, open_, size) in opened.items():
        declared[name] = _guarded(where, partial(_declared, open_, size))
        total += declared[name]
        if total > max_bytes:
            raise ValueError(f"{where} declares {declared[name]:,} bytes of array data, which brings the source to "
                             f"{total:,} bytes, more than the limit of {max_bytes:,} (max_source_bytes / "
                             "--max-source-bytes); import a smaller source or raise the limit")
    return {name: _guarded(where, partial(_read, open_)) for name, (where, open_, _) in opened.items()}


def _guarded(where: str, read: Callable[[], Any]) -> Any:
    """``read()``, with whatever a damaged file makes the readers raise as one line naming it."""
    try:
        return read()
    except ValueError as e:
        raise ValueError(f"{where}: {_one_line(e)}") from None
    except (EOFError, zlib.error, zipfile.BadZipFile, NotImplementedError, RuntimeError) as e:
        # RuntimeError: an encrypted member; NotImplementedError: a compression method zipfile lacks
        raise ValueError(f"{where}: truncated, corrupt or unreadable ({_one_line(e)})") from None
    except MemoryError:
        raise ValueError(f"{where}: not enough memory to read it") from None
    except OSError as e:
        raise storage_error(e, where, "reading") from None


def _declared(open_: Opener, size: int) -> int:
    """The data bytes an ``.npy`` header declares, after checking them against the ``size`` of the file."""
    with open_() as f:
        version = np.lib.format.read_magic(f)
        if version == (1, 0):
            shape, _, dtype = np.lib.format.read_array_header_1_0(f)
        elif version == (2, 0):
            shape, _, dtype = np.lib.format.read_array_header_2_0(f)
        else:
            raise ValueError(f".npy format version {version} is not supported (np.save writes 1.0)")
        header = f.tell()
    if dtype.hasobject or dtype.kind not in "biuf" or dtype.fields is not None or dtype.subdtype is not None:
        raise ValueError(f"holds dtype {dtype}; expected plain numeric arrays (bool, integer or float; no objects, "
                         "which would need unpickling)")
    data = math.prod(shape) * dtype.itemsize
    if header + data > size:
        raise ValueError(f"its header declares shape {list(shape)} of {dtype} ({data:,} bytes), but the file holds "
                         f"{max(size - header, 0):,} bytes of data: truncated or corrupt")
    return data


def _read(open_: Opener) -> np.ndarray:
    with open_() as f:
        return np.lib.format.read_array(f, allow_pickle=False)
