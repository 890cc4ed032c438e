"""Atomic file output, the one way this package writes anything a reader may see half-done.

``staged_directory`` fills a hidden sibling directory and renames it into place, replacing only a directory of
ours (``check_replaceable``); ``path_lock`` makes writers of one path take turns; ``write_atomic`` writes every
file a command writes through a temporary file and ``os.replace`` (a symbolic link is replaced, never followed;
a FIFO, device or directory is refused); ``storage_error`` makes an ``OSError`` one line naming the path (a full
disk: "no space left on <path>").
"""

from __future__ import annotations

import errno
import fcntl
import hashlib
import json
import logging
import os
import shutil
import stat
import threading
import uuid
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

log = logging.getLogger(__name__)


def sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 22), b""):
            h.update(chunk)
    return h.hexdigest()


def jsonable(x: Any) -> Any:
    """numpy scalars and arrays to Python numbers and lists, recursively."""
    if isinstance(x, dict):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, np.generic):
        return x.item()
    return x


# ---- I/O errors as one line naming the path -----------------------------------------------------------------

_DISK_FULL = (errno.ENOSPC, errno.EDQUOT)


class StorageError(OSError):
    """An ``OSError`` whose message names the path and what happened (``errno`` kept for callers)."""

    def __str__(self) -> str:  # not "[Errno 28] ...": the message already says it
        return str(self.strerror)


def storage_error(error: OSError, path: str | Path, doing: str, after: str = "") -> StorageError:
    """``error`` (raised while ``doing`` something with ``path``) as one line naming ``path``.

    A full disk is "no space left on <path>" (the device holding it, whichever file of it failed); any
    other error keeps its reason (``strerror``) and the file it names. ``after`` says what state that
    leaves (e.g. "nothing was written").
    """
    tail = f"; {after}" if after else ""
    if error.errno in _DISK_FULL:
        return StorageError(error.errno, f"no space left on {path} (while {doing}){tail}; free some space or "
                                         "choose another path")
    reason = error.strerror or str(error) or type(error).__name__
    where = f" ({error.filename})" if error.filename and str(error.filename) != str(path) else ""
    return StorageError(error.errno, f"{doing} {path} failed: {reason}{where}{tail}")


# ---- is this ours? ---------------------------------------------------------------------------------------

class NotReplaceableError(FileExistsError):
    """``path`` exists and is not a directory this package wrote, so it is never deleted or replaced."""


def check_replaceable(path: str | Path, marker: str, schema_version: int, what: str) -> None:
    """Raise ``NotReplaceableError`` unless ``path`` is a directory of ours (or does not exist).

    Ours: a real directory (not a symbolic link) whose ``marker`` file is readable JSON with
    ``"schema_version": schema_version``. ``what`` names the kind in the message ("icprl dataset").
    """
    path = Path(path)
    refuse = "refusing to delete or replace it, even with overwrite; remove it yourself or choose another path"
    if path.is_symlink():
        raise NotReplaceableError(f"{path} is a symbolic link (to {os.readlink(path)}), not {_a(what)}; {refuse}")
    if not path.exists():
        return
    if not path.is_dir():
        raise NotReplaceableError(f"{path} exists and is a file, not {_a(what)} directory; {refuse}")
    try:
        found = json.loads((path / marker).read_text())
    except FileNotFoundError:
        raise NotReplaceableError(f"{path} exists and is not {_a(what)} (it has no {marker}); {refuse}") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise NotReplaceableError(f"{path} exists and is not {_a(what)} ({marker} is unreadable: {e}); "
                                  f"{refuse}") from None
    version = found.get("schema_version") if isinstance(found, dict) else None
    if version != schema_version:
        raise NotReplaceableError(f"{path} exists and is not {_a(what)} of schema version {schema_version} "
                                  f"({marker} has schema_version {version!r}); {refuse}")


def _a(what: str) -> str:
    return f"an {what}" if what[:1].lower() in "aeiou" else f"a {what}"


# ---- one writer at a time ----------------------------------------------------------------------------------

def lock_file(path: str | Path) -> Path:
    path = Path(path)
    return path.parent / f".{path.name}.lock"


class _Held:
    def __init__(self) -> None:
        self.rlock = threading.RLock()  # threads of one process take turns; re-entrant per thread
        self.depth = 0
        self.fd: int | None = None


_HELD: dict[str, _Held] = {}
_HELD_GUARD = threading.Lock()


@contextmanager
def path_lock(path: str | Path) -> Iterator[bool]:
    """Hold an exclusive ``flock`` on ``<parent>/.<name>.lock`` (created holding the holder's pid, removed on
    release). Waits for another holder with a log line naming it. Re-entrant within a process.

    Yields whether the lock is held: False (after a warning) on a file system without ``flock``.
    """
    lock = lock_file(path)
    lock.parent.mkdir(parents=True, exist_ok=True)
    key = str(lock.resolve())
    with _HELD_GUARD:
        held = _HELD.setdefault(key, _Held())
    with held.rlock:
        if held.depth == 0:
            held.fd = _acquire(lock, Path(path))
        held.depth += 1
        try:
            yield held.fd is not None
        finally:
            held.depth -= 1
            if held.depth == 0 and held.fd is not None:
                fd, held.fd = held.fd, None
                lock.unlink(missing_ok=True)  # while still holding it; a waiter then sees a stale inode, retries
                os.close(fd)  # releases the flock


def _acquire(lock: Path, path: Path) -> int | None:
    """Open and flock ``lock``; retry when the file was unlinked by its previous holder meanwhile.

    None when the file system does not support ``flock``.
    """
    while True:
        fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o666)
        try:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                owner = os.pread(fd, 32, 0).decode(errors="replace").strip() or "?"
                log.warning("%s is being written by another process (pid %s, lock %s); waiting for it to finish",
                            path, owner, lock)
                fcntl.flock(fd, fcntl.LOCK_EX)
                log.warning("%s: the other process (pid %s) finished; continuing", path, owner)
            except OSError as e:
                if e.errno not in (errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOSYS, errno.EINVAL):
                    raise
                log.warning("%s: cannot lock %s (%s); writers of this path are not serialized", path, lock, e)
                os.close(fd)
                lock.unlink(missing_ok=True)
                return None
            try:
                current = os.stat(lock)
            except FileNotFoundError:
                current = None
            mine = os.fstat(fd)
            if current is None or (current.st_dev, current.st_ino) != (mine.st_dev, mine.st_ino):
                os.close(fd)  # the holder removed that file on release: lock the new one
                continue
            try:  # the holder's pid, for the waiting message only: a full disk must not leave the lock behind
                os.ftruncate(fd, 0)
                os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
            except OSError:
                pass
            return fd
        except BaseException:
            os.close(fd)
            raise


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, another user's
        return True
    return True


def _leftover_pid(name: str) -> int | None:
    """The pid in ``.<name>.tmp-<pid>-<hex>`` / ``.<name>.old-<pid>-<hex>``; None if the name has none."""
    try:
        return int(name.rsplit(".", 1)[1].split("-")[1])
    except (IndexError, ValueError):
        return None


def remove_stale(path: str | Path, lock_held: bool) -> list[Path]:
    """Remove the staging/trash leftovers of ``path`` no live process owns; return what was removed.

    Under the writers' lock (``lock_held``) every leftover is dead: each writer holds the lock while it
    stages, so none is another's live work (and a pid in a name, reused since, does not keep one
    forever). Without the lock only those whose pid (``.<name>.tmp-<pid>-<hex>``) is not alive go.
    """
    path = Path(path)
    removed = []
    for stale in [*path.parent.glob(f".{path.name}.tmp-*"), *path.parent.glob(f".{path.name}.old-*")]:
        pid = _leftover_pid(stale.name)
        if lock_held or (pid is not None and pid != os.getpid() and not _pid_alive(pid)):
            _rmtree(stale)
            removed.append(stale)
    return removed


def _rmtree(path: Path) -> None:
    if path.is_symlink() or path.is_file():
        path.unlink(missing_ok=True)
    else:
        shutil.rmtree(path, ignore_errors=True)


@contextmanager
def staged_directory(path: str | Path, *, marker: str, schema_version: int, what: str,
                     overwrite: bool = False) -> Iterator[Path]:
    """Yield a hidden sibling directory to fill; on success it replaces ``path`` by rename, on error it is removed.

    The staged directory must hold ``marker`` (the caller's manifest or summary with ``schema_version``)
    when the block ends. An existing ``path`` is refused with ``FileExistsError`` unless ``overwrite``, and
    with ``NotReplaceableError`` unless it is ours (``check_replaceable``) — checked before the block runs
    and again before the rename. The writer's lock (``path_lock``) is held throughout, so a second writer
    waits; leftovers of interrupted earlier runs that no live process owns are removed first. Nothing ever
    appears at ``path`` half-written.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)

    def check() -> None:
        if path.exists() or path.is_symlink():
            if not overwrite:
                raise FileExistsError(f"{path} exists; pass overwrite=True (--overwrite) to replace it")
            check_replaceable(path, marker, schema_version, what)

    with path_lock(path) as locked:
        check()
        for stale in remove_stale(path, lock_held=locked):
            log.info("removed %s, left by an interrupted earlier run", stale)
        tmp = path.parent / f".{path.name}.tmp-{os.getpid()}-{uuid.uuid4().hex[:8]}"
        tmp.mkdir()
        try:
            yield tmp
            if not (tmp / marker).is_file():
                raise RuntimeError(f"staged {what} for {path} has no {marker}; not moving it into place")
            check()
            if path.exists():
                trash = path.parent / f".{path.name}.old-{os.getpid()}-{uuid.uuid4().hex[:8]}"
                os.rename(path, trash)
                os.rename(tmp, path)
                shutil.rmtree(trash, ignore_errors=True)
            else:
                os.rename(tmp, path)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise


def check_writable(path: str | Path) -> None:
    """Refuse to write a file at ``path`` if something other than a regular file or a symbolic link is there (a
    FIFO would block the writer, a device would take the bytes, a directory is not a file): ``NotReplaceableError``
    naming it. A symbolic link is replaced by the file (``write_atomic``), never followed."""
    path = Path(path)
    try:
        mode = path.lstat().st_mode
    except FileNotFoundError:
        return
    if not (stat.S_ISREG(mode) or stat.S_ISLNK(mode)):
        raise NotReplaceableError(f"{path} is {file_kind(mode)}, not a file; refusing to write to it; remove it or "
                                  "choose another path")


def file_kind(mode: int) -> str:
    """What a file that is not a regular one is, from its ``st_mode``, for an error message."""
    return ("a directory" if stat.S_ISDIR(mode) else "a FIFO (named pipe)" if stat.S_ISFIFO(mode)
            else "a device" if stat.S_ISCHR(mode) or stat.S_ISBLK(mode) else "a special file")


def write_atomic(path: str | Path, content: bytes | str | Callable[[BinaryIO], Any]) -> Path:
    """Write ``content`` (bytes, text, or a function writing to a binary file) to ``path`` through a new
    temporary file in the same directory, flushed, then renamed over ``path``: a reader sees the old file or the
    new one, a symbolic link at ``path`` is replaced rather than followed, and a FIFO, device or directory there
    is refused (``check_writable``). An ``OSError`` is one line naming ``path`` (``storage_error``); on any
    failure the temporary file is removed and ``path`` is untouched."""
    path = Path(path)
    check_writable(path)
    tmp = path.parent / f".{path.name}.tmp-{os.getpid()}-{uuid.uuid4().hex[:8]}"
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        # O_EXCL: never write through a file or link someone else put at the temporary name
        with os.fdopen(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666), "wb") as f:
            if callable(content):
                content(f)
            else:
                f.write(content.encode() if isinstance(content, str) else content)
            f.flush()
            os.fsync(f.fileno())
        check_writable(path)
        os.replace(tmp, path)
    except OSError as e:
        tmp.unlink(missing_ok=True)
        if isinstance(e, NotReplaceableError | StorageError):
            raise
        raise storage_error(e, path, "writing", "nothing was written") from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path


def write_json_atomic(path: str | Path, payload: dict[str, Any]) -> Path:
    """Write ``payload`` as JSON through ``write_atomic``."""
    return write_atomic(path, json.dumps(jsonable(payload), indent=2) + "\n")


def save_figure(fig: Any, path: str | Path, **kwargs: Any) -> Path:
    """A matplotlib figure saved to ``path`` (its format from the suffix) through ``write_atomic``."""
    path = Path(path)
    return write_atomic(path, lambda f: fig.savefig(f, format=path.suffix.lstrip(".") or "png", **kwargs))


def payloads_in(folder: Path, kind) -> list[tuple[str, dict[str, Any]]]:
    """The JSON files of ``folder`` whose content ``kind`` accepts, by stem (unreadable ones skipped)."""
    out = []
    for path in sorted(folder.glob("*.json")):
        try:
            payload = json.loads(path.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError):
            continue
        if kind(payload):
            out.append((path.stem, payload))
    return out
