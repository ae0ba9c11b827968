"""Output paths checked before the work that writes to them: a typed error now, not a traceback later."""

from __future__ import annotations

import os
from pathlib import Path

from uiest.errors import OptionError

__all__ = ["plain_name", "writable_file", "writable_folder"]


def writable_folder(folder: Path, name: str) -> Path:
    """Create ``folder`` and check a file can be written there, else OptionError naming ``name``."""
    folder = Path(folder)
    probe = folder / f".write-test-{os.getpid()}"
    try:
        folder.mkdir(parents=True, exist_ok=True)
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as exc:
        raise OptionError(f"{name}: cannot write to {folder} ({exc.strerror or exc})") from None
    return folder


def writable_file(path: Path, name: str) -> Path:
    """Check ``path`` can be written as a file (its folder writable, itself not a folder)."""
    path = Path(path)
    if path.is_dir():
        raise OptionError(f"{name}: {path} is a folder; expected a file name")
    writable_folder(path.parent, name)
    return path


def plain_name(name: str, argument: str) -> str:
    r"""``name`` if it is one plain file or folder name (it will name a path inside an output folder), else OptionError.

    Refused: an empty name, an absolute path, a path separator (``/``, ``\``), ``.``, ``..`` and NUL,
    so a path built as ``folder / name`` stays inside ``folder``.
    """
    bad = not name or name in (".", "..") or any(sep in name for sep in ("/", "\\", "\0")) or Path(name).is_absolute()
    if bad:
        raise OptionError(
            f"{argument}: expected a plain name without path separators, '.' or '..' (it names a path inside the "
            f"output folder), got {name!r}"
        )
    return name
