"""Writing a file without ever losing the old one, and telling whether two paths name one file.

The low half of the output guard (:mod:`teamkf.study.outputs` is the whole of it): it sits this low
so that every layer that writes a file (the drop record and roster of :mod:`teamkf.deploy`, the
measurement and estimate files of :mod:`teamkf.study.measurements`) writes through the same
:func:`write_atomic`.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Any, Callable

from .exceptions import ArgumentError

__all__ = ["same_file", "write_atomic"]


def same_file(a: str | os.PathLike[str], b: str | os.PathLike[str]) -> bool:
    """Whether two paths name the same file: the same path in any spelling, a symbolic link to it, or a hard link to it.

    Existing files are compared by device and inode (:func:`os.path.samefile`), which catches every
    spelling, symbolic links (followed) and hard links; a path not there yet (or a dangling link) is
    compared by its resolved name, and is never the same as a missing ``b``.
    """
    try:
        return os.path.samefile(a, b)
    except (OSError, ValueError):
        try:  # a dangling link, or a file not there yet: compare the resolved names
            return Path(a).resolve() == Path(b).resolve() and Path(b).exists()
        except (OSError, RuntimeError, ValueError):
            return False


def write_atomic(path: str | os.PathLike[str], writer: Callable[[Any], Any], *, text: bool = False) -> None:
    """Write ``path`` through a temporary file in the same folder, renamed over it at the end.

    Parameters
    ----------
    path : path
        The target; its folder must exist (nothing is created but the file itself).
    writer : callable
        ``writer(fh)`` writes the content into the open file ``fh`` (binary, or text with ``text=True``).
    text : bool
        Open the temporary file in text mode (UTF-8).

    Notes
    -----
    On success the target is replaced in one step (:func:`os.replace`, atomic on POSIX and
    Windows); a reader sees the old file or the new one, never a part. On any exception
    (``KeyboardInterrupt`` included) the temporary file is removed, the target is untouched, and
    the exception propagates. An existing target keeps its permission bits. A target that is a
    symbolic link is replaced by the new file: the file the link pointed to is never written,
    and neither is the other name of a hard link.
    """
    target = Path(path)
    folder = target.parent if str(target.parent) else Path(".")
    if not folder.is_dir():
        raise ArgumentError(f"{target}: the folder {str(folder)!r} does not exist; create it first", argument=str(target))
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=folder)
    try:
        fh: Any = os.fdopen(fd, "w", encoding="utf-8", newline="") if text else os.fdopen(fd, "wb")
        with fh:
            writer(fh)
        try:
            mode = target.stat().st_mode & 0o777 if target.exists() and not target.is_symlink() else 0o666 & ~_umask()
            os.chmod(tmp, mode)
        except OSError:  # pragma: no cover - a file system without permission bits
            pass
        os.replace(tmp, target)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask
