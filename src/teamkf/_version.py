"""The version of teamkf (one place, importable from every layer; pyproject.toml reads it from here)."""

__version__ = "0.2.0"
