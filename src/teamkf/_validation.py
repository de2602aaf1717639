"""The one place where input checks and their messages live.

Every check names the argument as the caller wrote it (``"R[2]"``), says what
was expected and what was found, and suggests a fix.
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .exceptions import (
    ArgumentError,
    NotPositiveDefiniteError,
    NotSymmetricError,
    OptionalDependencyError,
    ShapeError,
)

FloatArray = NDArray[np.float64]

#: relative tolerance for symmetry and definiteness checks
SYM_RTOL = 1e-9


def frozen(a: FloatArray) -> FloatArray:
    """Return a read-only, C-contiguous float copy of ``a``."""
    out = np.array(a, dtype=float, order="C", copy=True)
    out.setflags(write=False)
    return out


def as_float_array(x: ArrayLike, name: str) -> FloatArray:
    """Convert to a float array; reject non-numeric input and non-finite values."""
    try:
        cplx = bool(np.iscomplexobj(x))
    except (TypeError, ValueError):  # ragged nested lists: reported as a shape error below
        cplx = False
    if cplx or (isinstance(x, (list, tuple)) and _has_complex(x)):
        raise ArgumentError(
            f"{name}: expected real numbers, found complex values; pass the real part explicitly if that is what you mean", argument=name
        )
    if isinstance(x, (str, bytes)) or x is None:
        raise ShapeError(f"{name}: expected a numeric array, found {describe(x)}; pass numbers (a list or a numpy array)", argument=name)
    kind = _element_kind(x)
    if kind:
        raise ShapeError(f"{name}: expected a numeric array, found {kind}; numpy would turn them into numbers silently: pass floats", argument=name)
    try:
        arr = np.asarray(x, dtype=float)
    except OverflowError:
        raise ShapeError(
            f"{name}: expected finite numbers, found an integer too large for a float (beyond 1.8e308); check how {name} was built"
        ) from None
    except (TypeError, ValueError) as exc:
        raise ShapeError(f"{name}: expected a numeric array, found {type(x).__name__} ({exc})") from None
    if not np.all(np.isfinite(arr)):
        raise ShapeError(f"{name}: expected finite numbers, found NaN or inf; check how {name} was built")
    return arr


def _element_kind(x: Any) -> str:
    """``"strings"`` or ``"booleans"`` when ``x`` holds them (which ``np.asarray(x, float)`` would convert), else ``""``."""
    if isinstance(x, (bool, np.bool_)):
        return "a boolean"
    if isinstance(x, np.ndarray):
        return {"U": "strings", "S": "strings", "b": "booleans"}.get(x.dtype.kind, "")
    if isinstance(x, (list, tuple)):
        stack: list[Any] = [x]
        seen = 0
        while stack and seen < 100_000:  # nested lists as written by hand; large arrays come as ndarrays
            v = stack.pop()
            seen += 1
            if isinstance(v, (list, tuple)):
                stack.extend(v)
            elif isinstance(v, (str, bytes)):
                return "strings"
            elif isinstance(v, (bool, np.bool_)):
                return "booleans"
    return ""


def _has_complex(x: Any) -> bool:
    if isinstance(x, complex):
        return True
    if isinstance(x, (list, tuple)):
        return any(_has_complex(e) for e in x)
    try:
        return bool(np.iscomplexobj(x))
    except (TypeError, ValueError):
        return False


def shape_str(shape: Sequence[int]) -> str:
    return "x".join(str(s) for s in shape) if len(shape) else "a scalar"


def matrix(x: ArrayLike, name: str, shape: tuple[int | None, int | None] | None = None) -> FloatArray:
    """A 2-D float matrix, optionally of a given shape (``None`` = any)."""
    arr = as_float_array(x, name)
    if arr.ndim != 2:
        want = "a 2-D matrix" if shape is None else f"a {shape_str([s if s is not None else 'k' for s in shape])} matrix"  # type: ignore[misc]
        raise ShapeError(f"{name}: expected {want}, found an array of shape {shape_str(arr.shape)}; write matrices as nested lists (rows)")
    if shape is not None:
        for ax, want_n in enumerate(shape):
            if want_n is not None and arr.shape[ax] != want_n:
                want = shape_str([s if s is not None else "k" for s in shape])  # type: ignore[misc]
                raise ShapeError(f"{name}: expected a {want} matrix, found {shape_str(arr.shape)}")
    return arr


def covariance(
    x: ArrayLike,
    name: str,
    dim: int | None = None,
    *,
    definite: bool = False,
) -> FloatArray:
    """A symmetric positive (semi-)definite matrix.

    A scalar ``q`` means ``q * I`` of size ``dim`` (which must then be given).
    """
    arr = as_float_array(x, name)
    kind = "positive definite" if definite else "positive semi-definite"
    if arr.ndim == 0:
        if dim is None:
            raise ShapeError(f"{name}: a scalar covariance needs a known dimension; write the full matrix")
        arr = float(arr) * np.eye(dim)
    if arr.ndim != 2 or arr.shape[0] != arr.shape[1] or (dim is not None and arr.shape[0] != dim):
        want = f"{dim}x{dim}" if dim is not None else "square"
        raise ShapeError(f"{name}: expected a {want} symmetric {kind} matrix, found {shape_str(arr.shape)}")
    scale = max(1.0, float(np.max(np.abs(arr)))) if arr.size else 1.0
    asym = float(np.max(np.abs(arr - arr.T))) if arr.size else 0.0
    if asym > SYM_RTOL * scale:
        raise NotSymmetricError(f"{name}: expected a symmetric matrix, found max |M - M'| = {asym:.3g}; use (M + M')/2 if the asymmetry is round-off")
    arr = 0.5 * (arr + arr.T)
    if arr.size:
        lam_min = float(np.linalg.eigvalsh(arr)[0])
        tol = SYM_RTOL * scale * arr.shape[0]  # round-off allowance for PSD
        tol_pd = 10 * arr.shape[0] * np.finfo(float).eps * scale  # numerically singular for PD
        if definite and lam_min <= tol_pd:
            raise NotPositiveDefiniteError(
                f"{name}: expected a symmetric positive definite matrix, found smallest eigenvalue {lam_min:.3g}; "
                "every noise covariance that is inverted must be strictly positive (add a small multiple of I)"
            )
        if not definite and lam_min < -tol:
            raise NotPositiveDefiniteError(f"{name}: expected a symmetric positive semi-definite matrix, found smallest eigenvalue {lam_min:.3g}")
    return arr


def integer(x: Any, name: str, *, minimum: int | None = None, maximum: int | None = None, what: str = "an integer") -> int:
    """An integer in [minimum, maximum] (bools rejected; a float with an integer value is accepted)."""
    bounds = (f" >= {minimum}" if minimum is not None else "") + (f" and <= {maximum}" if maximum is not None else "")
    if isinstance(x, (bool, np.bool_)) or not isinstance(x, (int, np.integer)):
        if isinstance(x, (float, np.floating)) and float(x).is_integer():
            x = int(x)
        else:
            raise ArgumentError(f"{name}: expected {what}{bounds}, found {describe(x)}", argument=name)
    if (minimum is not None and x < minimum) or (maximum is not None and x > maximum):
        raise ArgumentError(f"{name}: expected {what}{bounds}, found {x}", argument=name)
    return int(x)


def positive_int(x: Any, name: str, *, minimum: int = 1) -> int:
    """An integer ``>= minimum`` (bools are rejected)."""
    return integer(x, name, minimum=minimum)


def real(x: Any, name: str, *, minimum: float | None = None, maximum: float | None = None, strict: bool = False, what: str = "a number") -> float:
    """A finite real number in the given range (``strict``: the bounds themselves excluded); complex and bools rejected."""
    if isinstance(x, (bool, np.bool_)) or not isinstance(x, (int, float, np.integer, np.floating)):
        raise ArgumentError(f"{name}: expected {what}, found {describe(x)}", argument=name)
    try:
        v = float(x)
    except OverflowError:  # an integer beyond the float range (> 1.8e308)
        v = float("inf") if x > 0 else float("-inf")
    lo, hi = (">", "<") if strict else (">=", "<=")
    bounds = (f" {lo} {minimum:g}" if minimum is not None else "") + (f" and {hi} {maximum:g}" if maximum is not None else "")
    if not np.isfinite(v):
        raise ArgumentError(f"{name}: expected a finite {what.removeprefix('a ').removeprefix('an ')}{bounds}, found {v!r}", argument=name)
    below = minimum is not None and (v <= minimum if strict else v < minimum)
    above = maximum is not None and (v >= maximum if strict else v > maximum)
    if below or above:
        raise ArgumentError(f"{name}: expected {what}{bounds}, found {v:g}", argument=name)
    return v


def positive_float(x: Any, name: str, *, what: str = "a number") -> float:
    """A finite number > 0."""
    return real(x, name, minimum=0.0, strict=True, what=what)


def probability(x: Any, name: str) -> float:
    """A probability in [0, 1]."""
    return real(x, name, minimum=0.0, maximum=1.0, what="a probability")


def choice(x: Any, name: str, choices: Sequence[str], *, what: str = "one of") -> str:
    """One of ``choices`` (strings), with a "did you mean" hint for a near miss."""
    import difflib

    allowed = ", ".join(repr(c) for c in choices)
    if not isinstance(x, str):
        raise ArgumentError(f"{name}: expected {what} {allowed}, found {describe(x)}", argument=name)
    if x not in choices:
        close = difflib.get_close_matches(x, list(choices), n=1, cutoff=0.6)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        raise ArgumentError(f"{name}: expected {what} {allowed}, found {x!r}{hint}", argument=name)
    return x


def instance(x: Any, name: str, types: type | tuple[type, ...], what: str, fix: str = "") -> Any:
    """``x`` when it is one of ``types``; else an :class:`ArgumentError` naming ``name`` (the API's boundary check: no AttributeError later)."""
    if not isinstance(x, types):
        raise ArgumentError(f"{name}: expected {what}, found {describe(x)}{'; ' + fix if fix else ''}", argument=name)
    return x


def key_path(*parts: str | int) -> str:
    """Join a key path as the scenario reader writes it: ``key_path("agents", 2, "R") == "agents[2].R"``."""
    out = ""
    for p in parts:
        if isinstance(p, int):
            out += f"[{p}]"
        elif p:
            out += f".{p}" if out else p
    return out


def require(module: str, extra: str) -> Any:
    """Import an optional dependency or raise with the install command."""
    import importlib

    try:
        return importlib.import_module(module)
    except ImportError:
        raise OptionalDependencyError(
            f"{module} is needed for this feature but is not installed; install it with: pip install 'teamkf[{extra}]'"
        ) from None


def describe(x: Any) -> str:
    """A short description of a value read from a scenario file, for error messages."""
    from collections.abc import Mapping

    if x is None:
        return "None"
    if isinstance(x, bool):
        return f"the boolean {str(x).lower()}"
    if isinstance(x, (int, float)):
        return f"the number {x!r}"
    if isinstance(x, str):
        return f"the string {x!r}"
    if isinstance(x, list):
        return f"a list of {len(x)} items"
    if isinstance(x, Mapping):
        return "a table"
    return type(x).__name__


# ---------------------------------------------------------------------------
# environment settings: every TEAMKF_* variable teamkf reads, checked where it is read
# ---------------------------------------------------------------------------
#: the environment variables teamkf reads, and what each holds (``teamkf`` checks them all before a command runs)
ENVIRONMENT = {
    "TEAMKF_MAX_HOURS": "the work limit in hours (a finite number > 0; default 2)",
    "TEAMKF_PROGRESS": "progress bars on a terminal (0/false/no/off hides them; 1/true/yes/on or empty shows them)",
    "TEAMKF_CACHE_DIR": "the folder of the leaderboard's cache (off/0/none/no: no cache; default ~/.cache/teamkf)",
    "TEAMKF_WORKERS": "processes of teamkf reproduce (leaderboard, robustness, the bulk-* grids; a whole number >= 1; default: the number of cores)",
    "TEAMKF_PLUGINS": "plug-in modules or .py files to import, separated by the path separator",
}
#: variables the scripts in examples/ read (not the package): never warned about
EXAMPLES_ENVIRONMENT = ("TEAMKF_RUNS", "TEAMKF_T")
#: the values of a yes/no setting (TEAMKF_PROGRESS)
ENV_OFF = ("0", "false", "no", "off")
ENV_ON = ("1", "true", "yes", "on")


def _env_error(name: str, expected: str, text: str, fix: str) -> ArgumentError:
    return ArgumentError(f"{name}: expected {expected}, found {text!r}; {fix} (or unset it: unset {name})", argument=name)


def env_hours(name: str = "TEAMKF_MAX_HOURS", default: float = 2.0) -> float:
    """The number of hours in ``name`` (``default`` when unset or empty): finite and > 0, else one :class:`ArgumentError`.

    ``inf`` is refused on purpose, like ``--max-hours inf``: a job with no limit at all is written as a large
    number (``TEAMKF_MAX_HOURS=1e6``), so that a typo never lifts the limit.
    """
    import math
    import os

    text = os.environ.get(name, "")
    if not text.strip():
        return default
    try:
        hours = float(text)
    except ValueError:
        hours = math.nan
    if not (math.isfinite(hours) and hours > 0):
        inf = "; for no practical limit use a large number (1e6)" if not math.isnan(hours) and hours > 0 else ""
        raise _env_error(name, "a positive number of hours (e.g. 24)", text, f"set it to a finite number > 0{inf}")
    return hours


def env_switch(name: str) -> bool | None:
    """A yes/no setting: False for 0/false/no/off, True for 1/true/yes/on, None when unset or empty; else one :class:`ArgumentError`."""
    import os

    text = os.environ.get(name, "")
    word = text.strip().lower()
    if not word:
        return None
    if word in ENV_OFF or word in ENV_ON:
        return word in ENV_ON
    raise _env_error(name, "one of " + "/".join(ENV_OFF + ENV_ON), text, f"set {name}=0 to turn it off")


def env_count(name: str) -> int | None:
    """A whole number >= 1 in ``name`` (None when unset or empty); else one :class:`ArgumentError`."""
    import os

    text = os.environ.get(name, "")
    if not text.strip():
        return None
    try:
        v = int(text.strip())
    except ValueError:
        v = 0
    if v < 1:
        raise _env_error(name, "a whole number >= 1", text, "set it to e.g. 4")
    return v


def env_folder(name: str, off: Sequence[str] = ("off", "0", "none", "no")) -> str | None:
    """A folder in ``name``: "" when unset (the caller's default), None for one of ``off``; a path naming a file is an :class:`ArgumentError`."""
    import os

    text = os.environ.get(name, "")
    if text.strip().lower() in off:
        return None
    if "\0" in text:
        raise _env_error(name, "a folder path", text, "remove the NUL character")
    if text and os.path.exists(text) and not os.path.isdir(text):
        raise _env_error(name, f"a folder (or {'/'.join(off)})", text, "it names a file: give a folder")
    return text


def check_environment() -> list[str]:
    """Check every TEAMKF_* variable teamkf reads (one :class:`ArgumentError` for the first bad one).

    Returns
    -------
    list of str
        One warning line for each set ``TEAMKF_*`` variable teamkf does not read whose name is close to
        one it does (a typo such as ``TEAMKF_MAX_HOUR`` would otherwise be ignored without a word).
    """
    import difflib
    import os

    env_hours("TEAMKF_MAX_HOURS")
    env_switch("TEAMKF_PROGRESS")
    env_folder("TEAMKF_CACHE_DIR")
    env_count("TEAMKF_WORKERS")
    plugins = os.environ.get("TEAMKF_PLUGINS", "")
    if "\0" in plugins:
        raise _env_error("TEAMKF_PLUGINS", "module names or .py files", plugins, "remove the NUL character")
    notes = []
    for key in sorted(os.environ):
        if key.upper().startswith("TEAMKF") and key not in ENVIRONMENT and key not in EXAMPLES_ENVIRONMENT:
            close = difflib.get_close_matches(key.upper(), list(ENVIRONMENT), n=1, cutoff=0.9)
            if close:
                notes.append(f"{key} is not a setting teamkf reads, so it is ignored; did you mean {close[0]}?")
    return notes
