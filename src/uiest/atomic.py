"""Files written whole or not at all.

:func:`write_file` writes to a temporary name in the target's folder and renames it into place
(``os.replace``); :func:`staged_folder` does the same for a group of files (a report, a command's
outputs). A write that fails (disk full, permission denied, file-size limit) leaves the files
already there unchanged, removes what it wrote, and raises :class:`~uiest.errors.StorageError`
naming the path and the cause.
"""

from __future__ import annotations

import contextlib
import errno
import os
import shutil
import tempfile
import threading
from collections.abc import Callable, Collection, Iterable, Iterator
from pathlib import Path

from uiest.errors import StorageError

__all__ = ["remove_unwritten", "staged_folder", "storage_error", "write_bytes", "write_file", "write_text"]

STAGED_PREFIX, STAGED_SUFFIX = ".staged-", ".tmp"
"""How the temporary folders of :func:`staged_folder` are named (a run killed while writing leaves one)."""


def storage_error(exc: OSError, path: Path | str) -> StorageError:
    """The one-line :class:`StorageError` of a failed write of ``path``: the path and the system's cause."""
    cause = exc.strerror or str(exc) or type(exc).__name__
    return StorageError(f"cannot write {path}: {cause}", str(path))


def remove_unwritten(candidates: Iterable[Path], written: Collection[Path]) -> list[Path]:
    """Remove the ``candidates`` that exist and are not ``written`` (an earlier run's outputs); returns them, sorted.

    Raises :class:`~uiest.errors.StorageError` naming a file that cannot be removed.
    """
    stale = sorted(path for path in set(candidates) if path not in written and path.exists())
    for path in stale:
        try:
            path.unlink()
        except FileNotFoundError:
            continue
        except OSError as exc:
            raise storage_error(exc, path) from None
    return stale


def _temporary_name(path: Path) -> Path:
    return path.with_name(f".{path.name}.{os.getpid()}-{threading.get_ident()}.tmp")


def write_file(path: Path | str, write: Callable[[Path], object]) -> Path:
    """Call ``write(tmp)`` on a temporary name beside ``path``, then rename it to ``path``; returns ``path``.

    ``write`` must write the whole file to the path it is given (which does not end in ``path``'s
    suffix: give the format explicitly where a writer infers it from the name).
    Raises StorageError (the previous file at ``path``, if any, is left as it was).
    """
    path = Path(path)
    tmp = _temporary_name(path)
    try:
        write(tmp)
        os.replace(tmp, path)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            tmp.unlink()
        if isinstance(exc, OSError) and not isinstance(exc, StorageError):
            raise storage_error(exc, path) from None
        raise
    return path


def write_text(path: Path | str, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` whole or not at all (:func:`write_file`)."""
    return write_file(path, lambda tmp: tmp.write_text(text, encoding="utf-8"))


def write_bytes(path: Path | str, data: bytes) -> Path:
    """Write ``data`` to ``path`` whole or not at all (:func:`write_file`)."""
    return write_file(path, lambda tmp: tmp.write_bytes(data))


def _final(path: Path, stage: Path, folder: Path) -> Path:
    """Where ``path`` (a file in ``stage``, or any path) goes once the stage is moved into ``folder``."""
    return folder / path.name if path.parent == stage else path


@contextlib.contextmanager
def staged_folder(folder: Path | str) -> Iterator[Path]:
    """A temporary folder inside ``folder``; its files replace those of the same names when the block succeeds.

    The files written into the yielded folder (it must hold files only) are renamed into ``folder``
    once the block ends without an exception, all of them or none: the files they replace are first
    moved aside, and put back if a rename fails (the new files are then removed). On an exception in
    the block nothing is renamed. The temporary folder is removed in every case. An OSError becomes a
    StorageError naming the file by its final name where it is known (a :func:`write_file` into the
    stage, or an OSError with a file name), else ``folder``.
    """
    folder = Path(folder)
    try:
        stage = Path(tempfile.mkdtemp(prefix=STAGED_PREFIX, suffix=STAGED_SUFFIX, dir=folder))
    except OSError as exc:
        raise storage_error(exc, folder) from None
    try:
        yield stage
        _move_all(stage, folder)
    except StorageError as exc:  # a write_file into the stage: named by its final path
        final = _final(Path(exc.path), stage, folder)
        raise StorageError(str(exc).replace(exc.path, str(final)), str(final)) from None
    except OSError as exc:
        written = Path(exc.filename) if isinstance(exc.filename, str | os.PathLike) else folder
        raise storage_error(exc, _final(written, stage, folder)) from None
    finally:
        shutil.rmtree(stage, ignore_errors=True)


def _move_all(stage: Path, folder: Path) -> None:
    """Rename every file of ``stage`` into ``folder``, all or none (:func:`staged_folder`); OSError otherwise."""
    items = sorted(item for item in stage.iterdir() if item.name != _ASIDE)
    for item in items:
        target = folder / item.name
        if item.is_dir() or (target.is_dir() and not target.is_symlink()):
            wrong = item if item.is_dir() else target
            raise IsADirectoryError(errno.EISDIR, "a folder where a file is written", str(wrong))
    aside = stage / _ASIDE
    aside.mkdir()
    replaced: list[str] = []
    placed: list[str] = []
    try:
        for item in items:
            target = folder / item.name
            if target.exists() or target.is_symlink():
                os.replace(target, aside / item.name)
                replaced.append(item.name)
            os.replace(item, target)
            placed.append(item.name)
    except OSError:
        for name in placed:
            with contextlib.suppress(OSError):
                os.remove(folder / name)
        for name in replaced:
            with contextlib.suppress(OSError):
                os.replace(aside / name, folder / name)
        raise


_ASIDE = ".replaced"
"""The stage's sub-folder that holds the files being replaced until every new file is in place."""
