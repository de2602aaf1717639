"""The installed version of teamkf (one place, importable from every layer)."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("teamkf")
except PackageNotFoundError:  # pragma: no cover - running from a source tree
    __version__ = "0.2.0"
