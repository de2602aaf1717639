"""One colour per estimator family, the same in every figure.

Built-in families have fixed colours from the Okabe-Ito and Tableau palettes (distinguishable with
the common colour-vision deficiencies, and in grey print by their line styles); any other name (a
user's family) gets a colour of its own from a stable hash of its name, so it is the same in every
plot and every Python process. Variants keep their family's colour and differ by line style: ``honest``
solid, ``ideal`` dashed, ``stale`` dotted.

Examples
--------
>>> from teamkf.plotting.colors import family_color, family_style
>>> family_color("mtmse") == family_color("MTMSE") == family_color("J* (MTMSE)")
True
>>> family_style("kcf [ideal]") == {"color": family_color("kcf"), "linestyle": "--"}
True
>>> family_color("avg_kf") == family_color("avg_kf")  # a user's family: stable
True
"""

from __future__ import annotations

import re
import zlib

__all__ = ["family_color", "family_style", "family_of", "FAMILY_COLORS", "VARIANT_STYLES"]

#: the built-in families' colours
FAMILY_COLORS: dict[str, str] = {
    "centralized": "#000000",  # black: the bound
    "mtmse": "#0072B2",  # blue
    "mmse": "#E69F00",  # orange
    "kcf": "#009E73",  # green
    "cikf": "#CC79A7",  # purple-pink
    "diffusion": "#D55E00",  # vermillion
    "local": "#999999",  # grey: the floor
    "ci": "#56B4E9",  # sky blue
    "icf": "#8C564B",  # brown
    "hcmci": "#BCBD22",  # olive
    "mtmse_lossy": "#6A3D9A",  # dark purple: the drop-aware design
    "bulk": "#17BECF",  # cyan
    "lqg": "#7F7F7F",
}

#: colours for other names, picked by a stable hash of the name (none is a built-in family's)
_EXTRA = ("#9467BD", "#D62728", "#393B79", "#637939", "#8C6D31", "#843C39", "#7B4173", "#FF9896", "#98DF8A", "#C5B0D5", "#C49C94", "#FFBB78")

#: line style of each variant (the family's colour is kept)
VARIANT_STYLES: dict[str, str] = {"honest": "-", "ideal": "--", "stale": ":", "robust": "-."}

_ALIASES = {"kf": "centralized", "kalman": "centralized", "centralised": "centralized", "j*": "mtmse"}


def family_of(name: str) -> str:
    """The family a label belongs to: ``"kcf [honest]"``, ``"J KCF stale (MC)"`` and ``"kcf"`` give ``"kcf"``.

    Parameters
    ----------
    name : str
        A family name or a label that contains one (a table column, a legend entry).

    Returns
    -------
    str
        A built-in family's name when the label names one, else the label itself in lower case.

    Examples
    --------
    >>> family_of("J KCF ideal (MC)"), family_of("J* (MTMSE)"), family_of("my_filter")
    ('kcf', 'mtmse', 'my_filter')
    """
    text = str(name).strip().lower()
    if text in FAMILY_COLORS:
        return text
    words = re.findall(r"[a-z_]+\*?", text)
    for w in words:  # an exact family word first ("mmse" in "J mmse")
        if w in FAMILY_COLORS and w != "j":
            return w
    for w in words:
        if w in _ALIASES:
            return _ALIASES[w]
    return text


def family_color(name: str) -> str:
    """The colour of a family (or of a label naming one), the same in every figure.

    Parameters
    ----------
    name : str
        A registered family's name, or a label that contains it (``"kcf [ideal]"``).

    Returns
    -------
    str
        A hex colour: the built-in family's own, or for any other name one picked by a stable
        hash of the name (the same in every Python process).

    Examples
    --------
    >>> family_color("mtmse"), family_color("kcf [honest]") == family_color("kcf")
    ('#0072B2', True)
    """
    fam = family_of(name)
    if fam in FAMILY_COLORS:
        return FAMILY_COLORS[fam]
    return _EXTRA[zlib.crc32(fam.encode("utf-8")) % len(_EXTRA)]


def family_style(name: str) -> dict[str, str]:
    """Matplotlib keywords for a family's line: its colour, and a line style for its variant.

    Parameters
    ----------
    name : str
        A family name or label, possibly with a variant (``"kcf [ideal]"``, ``"J KCF stale (MC)"``).

    Returns
    -------
    dict
        ``{"color": ..., "linestyle": ...}``.

    Examples
    --------
    >>> family_style("kcf stale")
    {'color': '#009E73', 'linestyle': ':'}
    """
    words = set(re.findall(r"[a-z]+", str(name).lower()))
    style = next((VARIANT_STYLES[v] for v in ("ideal", "stale", "robust", "honest") if v in words), "-")
    return {"color": family_color(name), "linestyle": style}
