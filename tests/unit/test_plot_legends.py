"""Every figure the experiments write: one colour per family, and no legend over a panel's data.

Each experiment runs in quick mode (the robustness grid shrunk further) with its figures written to a
temporary folder; the figures are caught as they are saved and inspected in display coordinates.
The quick experiments that take more than a few seconds are marked slow.
"""

from __future__ import annotations

import importlib.util

import pytest

pytestmark = pytest.mark.skipif(importlib.util.find_spec("matplotlib") is None, reason="needs matplotlib (the plot extra)")

#: quick runs that take a few seconds at most; the others are marked slow
FAST = {"fig1", "table1", "bulk-stabilization", "bulk-timevarying"}  # robustness: its own fast test below


def _experiments() -> list:
    from teamkf.experiments import names

    return [pytest.param(name, marks=() if name in FAST else pytest.mark.slow) for name in names()]


@pytest.fixture
def saved_figures(monkeypatch):
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    figures: list = []
    original = Figure.savefig

    def savefig(self, *args, **kwargs):
        figures.append(self)
        return original(self, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", savefig)
    return figures


def _check_figure(fig, what: str) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.lines import Line2D

    from teamkf import families
    from teamkf.plotting import legend_overlaps
    from teamkf.plotting.colors import family_of

    FigureCanvasAgg(fig).draw()  # a figure pyplot closed has lost its canvas
    legends = [ax.get_legend() for ax in fig.axes if ax.get_legend() is not None] + list(fig.legends)
    for leg in legends:
        texts = [t.get_text() for t in leg.get_texts()]
        assert not legend_overlaps(leg, fig), f"{what}: the legend {texts[:4]} lies over a panel's data"
    registered = set(families())
    colours: dict[str, set[str]] = {}
    for ax in fig.axes:
        for line in ax.get_lines():
            label = line.get_label()
            if not isinstance(line, Line2D) or label.startswith("_"):
                continue
            fam = family_of(label.split(". ", 1)[-1])
            if fam in registered:
                colours.setdefault(fam, set()).add(matplotlib_hex(line.get_color()))
    for fam, cs in colours.items():
        assert len(cs) == 1, f"{what}: family {fam} is drawn in several colours {sorted(cs)}"
    owners: dict[str, str] = {}
    for fam, cs in colours.items():
        (c,) = cs
        assert c not in owners, f"{what}: families {owners.get(c)} and {fam} share the colour {c}"
        owners[c] = fam


def matplotlib_hex(color) -> str:
    from matplotlib.colors import to_hex

    return to_hex(color)


@pytest.mark.parametrize("name", _experiments())
def test_experiment_figures_one_colour_per_family_and_legends_off_the_data(name, tmp_path, saved_figures, monkeypatch):
    from teamkf.experiments import run

    if name == "robustness":  # the quick grid, smaller still: the figure is the same kind
        import teamkf.experiments.robustness as R

        monkeypatch.setattr(R, "P_QUICK", (0.0, 1.0))
        monkeypatch.setattr(R, "J_QUICK", (0, 1))
    res = run(name, tmp_path, quick=True)
    assert len(saved_figures) == len([f for f in res.figures if f.endswith(".png")]) and saved_figures, "every figure was caught"
    for fig in saved_figures:
        _check_figure(fig, name)


def test_robustness_colours_follow_the_families(tmp_path, saved_figures, monkeypatch):
    """Old: centralized and the drop-aware design's three series all black; the legend over the right panels."""
    import teamkf.experiments.robustness as R
    from teamkf.plotting.colors import family_color

    monkeypatch.setattr(R, "SCENARIOS", ("platoon-4",))
    monkeypatch.setattr(R, "P_QUICK", (0.0, 1.0))
    monkeypatch.setattr(R, "J_QUICK", (0,))
    R.run(tmp_path, True)
    (fig,) = saved_figures
    colour = {line.get_label(): matplotlib_hex(line.get_color()) for ax in fig.axes for line in ax.get_lines()}
    assert colour["centralized"] == family_color("centralized").lower()
    assert colour["mtmse_lossy"] == colour["mtmse_lossy (exact)"] == family_color("mtmse_lossy").lower() != colour["centralized"]
    assert len({colour[n] for n in ("centralized", "mtmse", "mmse", "kcf", "ci", "local", "mtmse_lossy")}) == 7
    _check_figure(fig, "robustness")


def test_legends_off_the_data_moves_a_legend_that_covers_the_data():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from teamkf.plotting import legend_overlaps, legends_off_the_data

    fig, axes = plt.subplots(1, 2)
    for ax in axes:
        ax.plot([0, 1], [0, 1], label="mtmse")
        ax.legend(loc="center")
    fig.canvas.draw()
    assert all(legend_overlaps(ax.get_legend(), fig) for ax in axes)
    assert legends_off_the_data(fig) == 2
    fig.canvas.draw()
    assert not any(legend_overlaps(ax.get_legend(), fig) for ax in axes)
    plt.close(fig)
    fig, ax = plt.subplots()
    (line,) = ax.plot([0, 1], [0, 1])
    fig.legend([line], ["mtmse"], loc="center")
    assert legends_off_the_data(fig) == 1
    fig.canvas.draw()
    assert not legend_overlaps(fig.legends[0], fig)
    plt.close(fig)
