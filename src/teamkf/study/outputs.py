"""Output paths that lose nothing: checked before any work, written atomically.

Every file or folder that a ``teamkf`` command writes goes through two functions:

* :func:`check_output` (or :func:`check_output_dir` for a results folder), called
  before any computation. It refuses, with one line naming the flag,

  - an output that is one of the command's inputs (the same file after resolving
    links and relative paths, :func:`os.path.samefile`): ``teamkf design base.toml
    --out base.toml`` would otherwise replace the scenario by an npz;
  - an output under a folder that does not exist (a typo must not become new
    folders): the message names the missing folder;
  - an extension that does not match the format written (``--out gains.txt`` for
    an npz), the rule pandas and numpy leave to the caller;
  - a folder where a file is expected, a file where a folder is expected, and a
    place that cannot be written.

* :func:`write_atomic`: the bytes go to a temporary file in the same folder,
  which is renamed over the target at the end (:func:`os.replace`, atomic on
  POSIX and Windows); on any failure, or an interrupt, the target is left as it
  was and the temporary file is removed.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

from ..exceptions import ArgumentError

__all__ = ["FORMATS", "check_output", "check_output_dir", "check_scheduler", "same_file", "write_atomic"]

#: the extensions of each output format (the first one is suggested in messages)
FORMATS: dict[str, tuple[str, ...]] = {
    "npz": (".npz",),
    "csv": (".csv",),
    "parquet": (".parquet",),
    "table": (".csv", ".parquet"),
    "json": (".json",),
    "png": (".png",),
    "plot": (".png", ".pdf", ".svg", ".jpg", ".jpeg"),
    "mcap": (".mcap",),
}


def _text(path: Any, flag: str) -> str:
    if isinstance(path, Path):
        path = str(path)
    if not isinstance(path, str):
        raise ArgumentError(f"{flag}: expected a file path (a string), found {type(path).__name__}", argument=flag)
    if not path.strip():
        raise ArgumentError(f"{flag}: expected a file path, found an empty string; give a file name", argument=flag)
    if "\x00" in path:
        raise ArgumentError(f"{flag}: expected a file path, found a NUL character in {path!r}; remove it", argument=flag)
    return path


def same_file(a: str | os.PathLike[str], b: str | os.PathLike[str]) -> bool:
    """Whether two paths name the same file (links and relative paths resolved); False when either is missing."""
    try:
        return os.path.samefile(a, b)
    except (OSError, ValueError):
        try:  # a dangling link, or a file not there yet: compare the resolved names
            return Path(a).resolve() == Path(b).resolve() and Path(b).exists()
        except (OSError, RuntimeError, ValueError):
            return False


def _check_inputs(p: Path, flag: str, inputs: Iterable[Any]) -> None:
    for inp in inputs:
        if inp is None:
            continue
        if same_file(p, str(inp)):
            raise ArgumentError(
                f"{flag}: {str(p)!r} is also an input of this command ({str(inp)!r}); writing there would destroy it; choose another output path",
                argument=flag,
            )


def _check_parent(p: Path, flag: str, path: str) -> None:
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.exists():
        missing = parent
        while not missing.parent.exists() and missing.parent != missing:
            missing = missing.parent
        raise ArgumentError(
            f"{flag}: cannot write {path!r}: the folder {str(missing)!r} does not exist; create it first (teamkf does not create folders) "
            "or fix the path",
            argument=flag,
        )
    if not parent.is_dir():
        raise ArgumentError(f"{flag}: cannot write {path!r}: {str(parent)!r} is a file, not a folder; choose another path", argument=flag)
    if not os.access(parent, os.W_OK | os.X_OK):
        raise ArgumentError(f"{flag}: cannot write {path!r}: no permission to write into {str(parent)!r}; choose another path", argument=flag)


def check_output(path: Any, flag: str, *, fmt: str | Sequence[str] | None = None, inputs: Iterable[Any] = ()) -> Path:
    """An output file path, checked before any work.

    Parameters
    ----------
    path : str or Path
        The output file as the user gave it.
    flag : str
        The option that gave it (``"--out"``), named in every message.
    fmt : str or sequence of str, optional
        The format written: a key of :data:`FORMATS` (``"npz"``, ``"table"``, ``"plot"``...)
        or the allowed extensions (``(".csv", ".parquet")``); the extension must be one of them.
    inputs : iterable of paths
        The command's input files; the output must not be any of them (compared with
        :func:`os.path.samefile`, so links and relative spellings are caught).

    Returns
    -------
    Path

    Raises
    ------
    teamkf.exceptions.ArgumentError
        Naming ``flag``: wrong extension, an input, a folder, a missing parent folder, no permission.
    """
    path = _text(path, flag)
    p = Path(path)
    if fmt is not None:
        suffixes = FORMATS[fmt] if isinstance(fmt, str) else tuple(fmt)
        if p.suffix.lower() not in suffixes:
            found = f"the extension {p.suffix!r}" if p.suffix else "no extension"
            stem = p.stem if p.suffix else p.name
            raise ArgumentError(
                f"{flag}: expected a file name ending in {' or '.join(suffixes)} (the format written), found {found} in {path!r}; "
                f"use e.g. {stem}{suffixes[0]}",
                argument=flag,
            )
    if p.is_dir():
        raise ArgumentError(f"{flag}: {path!r} is a directory; give a file name", argument=flag)
    _check_inputs(p, flag, inputs)
    _check_parent(p, flag, path)
    if p.exists() and not os.access(p, os.W_OK):
        raise ArgumentError(f"{flag}: cannot write {path!r}: the file is read-only; choose another path", argument=flag)
    return p


def check_output_dir(path: Any, flag: str, *, inputs: Iterable[Any] = ()) -> Path:
    """An output folder: an existing folder, or a new one whose parent exists; never one of the inputs or a file.

    Raises
    ------
    teamkf.exceptions.ArgumentError
        Naming ``flag``.
    """
    path = _text(path, flag)
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise ArgumentError(f"{flag}: expected a folder, found the file {path!r}; choose another path", argument=flag)
    _check_inputs(p, flag, inputs)
    if p.exists():
        if not os.access(p, os.W_OK | os.X_OK):
            raise ArgumentError(f"{flag}: cannot write into {path!r}: no permission; choose another path", argument=flag)
        return p
    _check_parent(p, flag, path)
    return p


def write_atomic(path: str | os.PathLike[str], writer: Callable[[Any], Any], *, text: bool = False) -> None:
    """Write ``path`` through a temporary file in the same folder, renamed over it at the end.

    Parameters
    ----------
    path : path
        The target; its folder must exist (:func:`check_output` said so before the work).
    writer : callable
        ``writer(fh)`` writes the content into the open file ``fh`` (binary, or text with ``text=True``).
    text : bool
        Open the temporary file in text mode (UTF-8).

    Notes
    -----
    On success the target is replaced in one step (:func:`os.replace`); a reader sees
    the old file or the new one, never a part. On any exception (``KeyboardInterrupt``
    included) the temporary file is removed, the target is untouched, and the
    exception propagates. An existing target keeps its permission bits.
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
            mode = target.stat().st_mode & 0o777 if target.exists() else 0o666 & ~_umask()
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


def check_scheduler(address: str, flag: str = "scheduler") -> None:
    """Fail fast (2 s) when a Dask scheduler address is malformed or nothing listens there."""
    import socket
    from urllib.parse import urlsplit

    if address in ("local", "serial"):
        return
    parts = urlsplit(address if "://" in address else f"tcp://{address}")
    try:
        host, port = parts.hostname, parts.port
    except ValueError:
        host, port = None, None
    if parts.scheme not in ("tcp", "tls", "ws", "wss", "inproc", "ucx") or not host or port is None:
        raise ArgumentError(f"{flag}: expected 'serial', 'local' or a Dask scheduler address like tcp://host:8786, found {address!r}", argument=flag)
    try:
        with socket.create_connection((host, port), timeout=2.0):
            pass
    except OSError as exc:
        raise ArgumentError(
            f"{flag}: cannot reach a Dask scheduler at {address!r} ({exc.strerror or exc}); start one (dask scheduler) or use 'local' / 'serial'",
            argument=flag,
        ) from None
