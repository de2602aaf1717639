"""The output guard: every file a ``teamkf`` command writes is checked before any work and written atomically.

Every output of every command (``--out``, ``--plot``, ``--record``, ``--report``, ``--stream``,
the files of a results folder, the cache) goes through this module:

* :func:`check_output` (or :func:`check_output_dir` for a results folder), called
  before any computation. It refuses, with one line naming the flag,

  - an output that is one of the command's inputs (:func:`command_inputs`: the files named
    on the command line and every plug-in file loaded) in any spelling: the same path, a
    relative spelling, a symbolic link to the input, or a hard link to it (compared by device
    and inode, :func:`os.path.samefile`): ``teamkf design base.toml --out base.toml`` would
    otherwise replace the scenario by an npz;
  - an output that is another output of the same command (``teamkf deploy --out x --record x``);
  - an output under a folder that does not exist (a typo must not become new
    folders): the message names the missing folder; teamkf creates no folder but a
    results folder the user named, and only when its parent exists;
  - an extension that does not match the format written (``--out gains.txt`` for
    an npz), the rule pandas and numpy leave to the caller;
  - a folder where a file is expected, a file where a folder is expected, and a
    place that cannot be written.

* :func:`write_atomic`: the bytes go to a temporary file in the same folder,
  which is renamed over the target at the end (:func:`os.replace`, atomic on
  POSIX and Windows); on any failure, or an interrupt, the target is left as it
  was and the temporary file is removed. A target that is a symbolic link is
  replaced; the file it pointed to is never written.

* :func:`open_stream`, the one exception: ``teamkf agent --stream`` appends each estimate as it is
  computed, so that a killed agent leaves the steps it finished; no rename can do that. The file is
  opened without following a symbolic link and without truncating, compared (device and inode)
  with every input, and only then emptied.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path
from typing import IO, Any, Iterable, Sequence

from .._files import same_file, write_atomic
from ..exceptions import ArgumentError

__all__ = [
    "FORMATS",
    "check_output",
    "check_output_dir",
    "check_scheduler",
    "command_inputs",
    "open_stream",
    "same_file",
    "write_atomic",
]

#: the extensions of each output format (the first one is suggested in messages)
FORMATS: dict[str, tuple[str, ...]] = {
    "npz": (".npz",),
    "csv": (".csv",),
    "parquet": (".parquet",),
    "table": (".csv", ".parquet"),
    "json": (".json",),
    "png": (".png",),
    "plot": (".png", ".pdf", ".svg", ".jpg", ".jpeg"),
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


def plugin_files() -> list[str]:
    """The files of the plug-ins loaded in this process and named in ``TEAMKF_PLUGINS``: inputs of every command."""
    import sys

    from ..estimators.registry import PLUGINS_ENV, loaded_plugins

    files = []
    for name, path, _ in loaded_plugins():
        where = path if path is not None else getattr(sys.modules.get(name), "__file__", None)
        if where:
            files.append(str(where))
    files += [s for s in os.environ.get(PLUGINS_ENV, "").split(os.pathsep) if s.endswith(".py")]
    return files


def command_inputs(*paths: Any) -> list[str]:
    """The input files of a command: ``paths`` (None, ``"-"`` and names that are not files are kept; they match nothing) and :func:`plugin_files`."""
    return [str(p) for p in paths if p is not None and str(p) != "-"] + plugin_files()


def _how(p: Path, inp: str) -> str:
    try:
        if p.is_symlink():
            return ", through a symbolic link"
        if os.path.exists(inp) and Path(os.path.abspath(p)) != Path(os.path.abspath(inp)) and p.resolve() != Path(inp).resolve():
            return ", a hard link to it"
    except OSError:  # pragma: no cover
        pass
    return ""


def _check_inputs(p: Path, flag: str, inputs: Iterable[Any]) -> None:
    for inp in [*inputs, *plugin_files()]:
        if inp is None:
            continue
        if same_file(p, str(inp)):
            raise ArgumentError(
                f"{flag}: {str(p)!r} is also an input of this command ({str(inp)!r}{_how(p, str(inp))}); "
                "writing there would destroy it; choose another output path",
                argument=flag,
            )


def _same_target(a: Path, b: Path) -> bool:
    """Whether two outputs would land in one file (either may not exist yet)."""
    if same_file(a, b):
        return True
    try:
        return a.resolve() == b.resolve()
    except (OSError, RuntimeError):  # pragma: no cover
        return False


def _check_others(p: Path, flag: str, outputs: Iterable[tuple[Any, str]]) -> None:
    for other, other_flag in outputs:
        if other is not None and _same_target(p, Path(str(other))):
            raise ArgumentError(
                f"{flag}: {str(p)!r} is also the {other_flag} of this command; two outputs cannot share a file; choose another path",
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


def check_output(
    path: Any,
    flag: str,
    *,
    fmt: str | Sequence[str] | None = None,
    inputs: Iterable[Any] = (),
    outputs: Iterable[tuple[Any, str]] = (),
) -> Path:
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
        :func:`os.path.samefile`, so relative spellings, symbolic links and hard links are
        caught). The plug-in files loaded (:func:`plugin_files`) are always inputs.
    outputs : iterable of (path, flag)
        The command's other outputs, already checked; the output must not be any of them.

    Returns
    -------
    Path

    Raises
    ------
    teamkf.exceptions.ArgumentError
        Naming ``flag``: wrong extension, an input, another output, a folder, a missing parent folder, no permission.
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
    _check_others(p, flag, outputs)
    _check_parent(p, flag, path)
    if p.exists() and not os.access(p, os.W_OK):
        raise ArgumentError(f"{flag}: cannot write {path!r}: the file is read-only; choose another path", argument=flag)
    return p


def check_output_dir(path: Any, flag: str, *, inputs: Iterable[Any] = ()) -> Path:
    """An output folder: an existing folder, or a new one whose parent exists; never one of the inputs or a file.

    Only the folder itself may be created later (by the command that writes into it), never a
    missing parent. The files written into it go through :func:`write_atomic`.

    Raises
    ------
    teamkf.exceptions.ArgumentError
        Naming ``flag``.
    """
    path = _text(path, flag)
    p = Path(path)
    _check_inputs(p, flag, inputs)
    if p.exists() and not p.is_dir():
        raise ArgumentError(f"{flag}: expected a folder, found the file {path!r}; choose another path", argument=flag)
    if p.exists():
        if not os.access(p, os.W_OK | os.X_OK):
            raise ArgumentError(f"{flag}: cannot write into {path!r}: no permission; choose another path", argument=flag)
        return p
    _check_parent(p, flag, path)
    return p


def open_stream(path: Any, flag: str, *, inputs: Iterable[Any] = ()) -> IO[bytes]:
    """Open an append-as-you-go output (``teamkf agent --stream``), emptied only once it is known not to be an input.

    The one output not written by :func:`write_atomic`: its rows must reach the disk as they are
    computed, so that a process killed mid-run leaves the steps it finished. Call :func:`check_output`
    first (before any work); this opens the file without following a symbolic link
    (``O_NOFOLLOW``) and without truncating it, compares the open file (device and inode) with
    every input, and only then empties a regular file (a FIFO or a device is written as it is).

    Raises
    ------
    teamkf.exceptions.ArgumentError
        Naming ``flag``: a symbolic link, an input (any spelling or hard link), a file that cannot be opened.
    """
    path = _text(path, flag)
    if Path(path).is_symlink():
        raise ArgumentError(
            f"{flag}: {path!r} is a symbolic link; a stream is written in place, so give the file itself (or a new name)", argument=flag
        )
    flags = os.O_WRONLY | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0) | getattr(os, "O_BINARY", 0)
    try:
        fd = os.open(path, flags, 0o666)
    except OSError as exc:
        raise ArgumentError(f"{flag}: cannot open {path!r} for writing ({exc.strerror}); choose another path", argument=flag) from None
    try:
        st = os.fstat(fd)
        for inp in [*inputs, *plugin_files()]:
            if inp is None:
                continue
            try:
                other = os.stat(str(inp))
            except (OSError, ValueError):
                continue
            if (st.st_dev, st.st_ino) == (other.st_dev, other.st_ino):
                raise ArgumentError(
                    f"{flag}: {path!r} is also an input of this command ({str(inp)!r}); writing there would destroy it; choose another output path",
                    argument=flag,
                )
        if stat.S_ISREG(st.st_mode):
            os.ftruncate(fd, 0)
        return os.fdopen(fd, "wb")
    except BaseException:
        os.close(fd)
        raise


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
