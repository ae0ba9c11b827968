"""One run per output folder: a lock file naming its owner (pid, host), held while a run writes there.

:func:`folder_lock` creates ``FOLDER/.uiest.lock`` holding the owner's pid, host and start time
and takes an exclusive ``flock`` on it. Another process asking for the same folder is refused
with a :class:`~uiest.errors.StorageError` naming the folder and the owner. The kernel releases
the ``flock`` when its owner ends in any way, so a lock file left by a run that was killed is
taken over, with a warning naming the run that left it (the staged folders it left unfinished,
:func:`uiest.atomic.staged_folder`, are removed). Within one process the lock is
re-entrant (a command holding it may call a function that asks for it again).
"""

from __future__ import annotations

import contextlib
import datetime as dt
import fcntl
import functools
import inspect
import json
import os
import shutil
import socket
import warnings
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import ParamSpec, TypeVar

from uiest.atomic import STAGED_PREFIX, STAGED_SUFFIX
from uiest.errors import StorageError
from uiest.paths import writable_folder

__all__ = ["LOCK_NAME", "folder_lock", "holds_folder"]

LOCK_NAME = ".uiest.lock"
"""Name of the lock file inside a locked folder."""

_held: dict[Path, int] = {}
"""Folders this process holds (resolved path -> nesting depth)."""

Params = ParamSpec("Params")
Result = TypeVar("Result")


def _owner(text: str) -> str:
    """The owner a lock file's text names, for a message."""
    try:
        record = json.loads(text)
        return f"pid {record['pid']} on host {record['host']}, since {record['started']}"
    except (ValueError, KeyError, TypeError):
        return "an unknown owner (unreadable lock file)"


def _read(fd: int) -> str:
    os.lseek(fd, 0, os.SEEK_SET)
    return os.read(fd, 4096).decode(errors="replace").strip()


def _acquire(folder: Path, name: str) -> int:
    """The descriptor of ``folder``'s lock file, locked and naming this process; StorageError if in use."""
    path = folder / LOCK_NAME
    while True:
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as exc:
            message = f"{name}: cannot create the lock file {path}: {exc.strerror or exc}"
            raise StorageError(message, str(path)) from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            owner = _owner(_read(fd))
            os.close(fd)
            raise StorageError(
                f"{name}: {folder} is in use by another run ({owner}); wait for it to end or choose another folder",
                str(folder),
            ) from None
        try:  # the previous owner removes the file when it ends: the one locked must still be the one named
            same = os.path.samestat(os.fstat(fd), os.stat(path))
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)
    try:
        previous = _read(fd)
        if previous:
            leftovers = sorted(folder.glob(f"{STAGED_PREFIX}*{STAGED_SUFFIX}"))
            for stage in leftovers:  # what that run was writing when it ended: never moved into the folder
                shutil.rmtree(stage, ignore_errors=True)
            removed = f"; removed the {len(leftovers)} unfinished write(s) it left" if leftovers else ""
            warnings.warn(
                f"{name}: took over the lock of {folder} left by a run that ended without releasing it "
                f"({_owner(previous)}){removed}",
                stacklevel=4,
            )
        record = {"pid": os.getpid(), "host": socket.gethostname(),
                  "started": dt.datetime.now(dt.UTC).isoformat(timespec="seconds")}  # fmt: skip
        os.ftruncate(fd, 0)
        os.lseek(fd, 0, os.SEEK_SET)
        os.write(fd, json.dumps(record).encode())
    except OSError as exc:
        _release(folder, fd)
        raise StorageError(f"{name}: cannot write the lock file {path}: {exc.strerror or exc}", str(path)) from None
    return fd


def _release(folder: Path, fd: int) -> None:
    with contextlib.suppress(OSError):
        os.unlink(folder / LOCK_NAME)  # still holding the lock: whoever opened this file sees it removed
    os.close(fd)


@contextlib.contextmanager
def folder_lock(folder: Path | str, name: str) -> Iterator[Path]:
    """Hold ``folder`` (an existing folder) for this process for the block; ``name`` labels messages.

    Raises
    ------
    StorageError
        Another process holds the folder (the message names it and the owner), or the lock file
        cannot be written.

    """
    folder = Path(folder)
    key = folder.resolve()
    if key in _held:
        _held[key] += 1
        try:
            yield folder
        finally:
            _held[key] -= 1
        return
    fd = _acquire(folder, name)
    _held[key] = 1
    try:
        yield folder
    finally:
        del _held[key]
        _release(folder, fd)


def holds_folder(argument: str) -> Callable[[Callable[Params, Result]], Callable[Params, Result]]:
    """Decorate a function so that it holds the folder given as its ``argument`` while it runs.

    The folder is created if missing. A value that is not a path is passed on unchecked (the
    function's own checks name it).
    """

    def decorate(function: Callable[Params, Result]) -> Callable[Params, Result]:
        signature = inspect.signature(function)

        @functools.wraps(function)
        def wrapper(*args: Params.args, **kwargs: Params.kwargs) -> Result:
            try:
                folder = signature.bind(*args, **kwargs).arguments.get(argument)
            except TypeError:
                folder = None
            if not isinstance(folder, str | os.PathLike):
                return function(*args, **kwargs)
            with folder_lock(writable_folder(Path(folder), argument), argument):
                return function(*args, **kwargs)

        return wrapper

    return decorate
