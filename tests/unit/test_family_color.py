"""One colour per family in every plot: fixed for teamkf's families, stable and hash-picked for any other."""

import re
import subprocess
import sys

import teamkf
from teamkf.plotting import family_color
from teamkf.plotting.colors import EXTRA_COLORS, FAMILY_COLORS


def test_every_builtin_family_has_its_own_colour():
    builtin = [n for n in teamkf.families() if n in FAMILY_COLORS]
    assert {"mtmse", "mmse", "centralized", "kcf", "cikf", "local", "diffusion", "ci", "icf", "hcmci"} <= set(builtin)
    colours = [family_color(n) for n in builtin]
    assert len(set(colours)) == len(colours)
    assert all(re.fullmatch(r"#[0-9a-f]{6}", c) for c in colours)
    assert family_color("kcf [honest]") == family_color("kcf") == family_color("KCF tuned")


def test_unknown_families_get_a_stable_colour_across_processes():
    names = ["my_filter", "avg", "plugin_kf"]
    here = [family_color(n) for n in names]
    assert all(c in EXTRA_COLORS for c in here)
    code = f"from teamkf.plotting import family_color; print([family_color(n) for n in {names!r}])"
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, env={"PYTHONHASHSEED": "123", **__import__("os").environ}
    )
    assert out.stdout.strip() == str(here)
