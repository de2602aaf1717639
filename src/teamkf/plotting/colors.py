"""One colour per estimator family, the same in every plot of the package.

teamkf's own families have fixed colours (:data:`FAMILY_COLORS`, the
colour-blind-safe Okabe–Ito and Tableau hues); any other name (a user's or a
plugin's family, a design label not in the table) gets a colour from
:data:`EXTRA_COLORS` chosen by a CRC-32 of its name, so it is the same in every
process and every run. No matplotlib is needed (hex strings).

Examples
--------
>>> family_color("mtmse")
'#000000'
>>> family_color("my_filter") == family_color("my_filter")
True
"""

from __future__ import annotations

import zlib

__all__ = ["FAMILY_COLORS", "EXTRA_COLORS", "family_color"]

#: teamkf's families (and the leaderboard's bound rows) -> colour
FAMILY_COLORS: dict[str, str] = {
    "mtmse": "#000000",
    "mtmse_lossy": "#555555",
    "mtmse-lossy": "#555555",
    "centralized": "#999999",
    "mmse": "#8c564b",
    "cikf": "#6a3d9a",
    "kcf": "#d55e00",
    "local": "#bcbd22",
    "diffusion": "#0072b2",
    "ci": "#009e73",
    "icf": "#cc79a7",
    "hcmci": "#e69f00",
    "bulk": "#17becf",
}

#: colours for every other family, picked by a stable hash of the name
EXTRA_COLORS: tuple[str, ...] = ("#393b79", "#637939", "#8c6d31", "#843c39", "#7b4173", "#3182bd", "#31a354", "#756bb1", "#636363", "#e6550d")


def family_color(name: str) -> str:
    """The colour of family ``name`` (hex ``"#rrggbb"``): fixed for teamkf's families, a stable hash-picked one otherwise.

    A label with a variant (``"kcf [honest]"``, ``"icf heard"``) takes its family's colour (the first word).
    """
    key = str(name).strip().split(" ")[0].split("[")[0].lower()
    if key in FAMILY_COLORS:
        return FAMILY_COLORS[key]
    return EXTRA_COLORS[zlib.crc32(key.encode()) % len(EXTRA_COLORS)]
