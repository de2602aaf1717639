"""Pictures and notebook tables: CommGraph.plot, InformationStructure.plot, _repr_html_ and .plot() of results."""

from __future__ import annotations

import re

import numpy as np
import pytest

pytest.importorskip("matplotlib")
import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from teamkf import (  # noqa: E402
    CommGraph,
    InformationStructure,
    LinearGaussianSystem,
    TeamCost,
    design_centralized,
    design_kcf,
    design_mmse,
    design_mtmse,
    experiments,
)
from teamkf._repr import DesignReprMixin, format_value, html_table  # noqa: E402
from teamkf.exceptions import ArgumentError  # noqa: E402
from teamkf.plotting.network import COMMON, LOCAL, NOT_HELD, edge_delay_labels, information_grid  # noqa: E402
from teamkf.simulation.monte_carlo import monte_carlo  # noqa: E402
from teamkf.study.results import CostCurves, SweepResult  # noqa: E402


@pytest.fixture(autouse=True)
def _close_figures():
    yield
    plt.close("all")


def _cells(html: str) -> list[str]:
    return re.findall(r"<t[dh](?:\s[^>]*)?>(.*?)</t[dh]>", html)


# --- CommGraph.plot ------------------------------------------------------------------------------
ASYM = CommGraph.from_edges(4, [(0, 1, 1), (1, 0, 1), (1, 2, 2), (2, 1, 1), (2, 3, 1), (3, 2, 1), (3, 0, 3)])


def test_edge_labels_are_the_delays():
    labels = edge_delay_labels(ASYM)
    assert set(labels) == {(0, 1), (1, 2), (2, 3), (0, 3)}
    assert labels[(0, 1)] == "1" and labels[(2, 3)] == "1"
    assert labels[(1, 2)] == "1→2: 2\n2→1: 1"  # asymmetric delays: both directions
    assert labels[(0, 3)] == "3→0: 3"  # one-way edge


@pytest.mark.parametrize("layout", ["circular", "spring", "kamada_kawai"])
def test_graph_plot_draws_nodes_edges_and_delay_labels(layout):
    ax = ASYM.plot(layout=layout)
    texts = [t.get_text() for t in ax.texts]
    for lab in edge_delay_labels(ASYM).values():
        assert lab in texts
    for i in range(4):
        assert str(i) in texts
    assert "τ* = 4" in ax.get_title()  # 0 -> 3 takes 1 + 2 + 1 steps
    assert len(ax.patches) == ASYM.n_edges  # one arrow per directed edge


def test_graph_plot_on_given_axes_and_positions():
    fig, ax = plt.subplots()
    g = CommGraph.line(3, delay=2)
    out = g.plot(ax=ax, layout={0: (0, 0), 1: (1, 0), 2: (2, 0)}, node_labels=["a", "b", "c"], title="line")
    assert out is ax and ax.get_title() == "line"
    assert {"a", "b", "c", "2"} <= {t.get_text() for t in ax.texts}


def test_graph_plot_bad_arguments():
    with pytest.raises(ArgumentError, match="layout: expected one of"):
        ASYM.plot(layout="circle")
    with pytest.raises(ArgumentError, match="node_labels: expected 4 labels"):
        ASYM.plot(node_labels=["a"])
    with pytest.raises(ArgumentError, match=r"layout: expected a position for every agent, found none for \[3\]"):
        ASYM.plot(layout={0: (0, 0), 1: (1, 0), 2: (2, 0)})


# --- InformationStructure.plot -----------------------------------------------------------------
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_information_grid_matches_holds_and_geodesic_delays(seed):
    graph = CommGraph.random(5, p=0.4, delays=(1, 3), rng=seed)
    S = InformationStructure.from_graph(graph)
    ell = graph.geodesic_delays()  # ell[j, i]: from j to i
    c = S.common_lag
    k = 3 * c + 2
    for i in range(5):
        grid = information_grid(S, i)
        assert grid.shape == (c + 1, 5)
        held = S.holds(i, k)
        for lag in range(c + 1):
            for j in range(5):
                assert ((j, k - lag) in held) == (grid[lag, j] != NOT_HELD)
                assert (grid[lag, j] == COMMON) == (lag >= c)
                # eq. (14): agent i holds y_j(k - lag) iff lag >= ell_ji
                assert (grid[lag, j] != NOT_HELD) == (lag >= ell[j, i])


def test_information_plot_one_panel_per_agent_with_the_grid():
    S = InformationStructure.own_window(3, common_lag=3, length=2)  # IS2-like
    axs = S.plot()
    assert len(axs) == 3
    for i, ax in enumerate(axs):
        img = ax.get_images()[0].get_array()
        np.testing.assert_array_equal(np.asarray(img), information_grid(S, i))
        assert ax.get_title() == f"agent {i}"
    grid = information_grid(S, 1)
    assert grid[0, 1] == LOCAL and grid[1, 1] == LOCAL and grid[2, 1] == NOT_HELD and grid[0, 0] == NOT_HELD


def test_information_plot_subset_and_errors():
    S = InformationStructure.delayed_sharing(4, 2)
    fig, ax = plt.subplots()
    assert S.plot(ax=ax, agents=[2], max_lag=4) is ax
    assert np.asarray(ax.get_images()[0].get_array()).shape == (5, 4)
    with pytest.raises(ArgumentError, match="ax: expected 2 axes"):
        S.plot(ax=ax, agents=[0, 1])
    with pytest.raises(ArgumentError, match="agent: expected an agent index in 0..3"):
        information_grid(S, 4)


# --- notebook tables ------------------------------------------------------------------------------
def test_html_table_escapes_and_marks_published_columns():
    html = html_table(["name", "paper value"], [{"name": "<b>x</b>", "paper value": 1.0}], published=lambda c: "paper" in c)
    assert "&lt;b&gt;x&lt;/b&gt;" in html and "<b>x</b>" not in html
    assert html.count('class="teamkf-published"') == 2  # header and cell
    long = html_table(["i"], [{"i": k} for k in range(100)], max_rows=10)
    assert "90 rows not shown" in long and _cells(long)[:6] == ["i", "0", "1", "2", "3", "4"] and _cells(long)[-1] == "99"
    assert (
        format_value(float("inf")) == "∞ (diverged)"
        and format_value(float("nan")) == "diverged"
        and format_value(None) == ""
        and format_value(0.1234567891) == "0.123457"
    )


@pytest.fixture(scope="module")
def platoon():
    system = LinearGaussianSystem.platoon(3)
    cost = TeamCost.platoon(3, lam=10.0)
    graph = CommGraph.line(3, delay=1)
    return system, cost, graph


def test_design_html_shows_family_horizon_and_analytic_cost(platoon):
    system, cost, graph = platoon
    for d in (
        design_mtmse(system, cost, graph, horizon=20),
        design_mmse(system, cost, graph, horizon=20),
        design_centralized(system, cost, horizon=20),
    ):
        html = DesignReprMixin._repr_html_(d)
        cells = _cells(html)
        assert d.estimator in cells and "20" in cells
        assert format_value(float(np.sum(d.stage_costs))) in cells
    steady = design_mtmse(system, cost, graph)
    cells = _cells(DesignReprMixin._repr_html_(steady))
    assert "∞ (steady state)" in cells and format_value(steady.average_cost) in cells
    kcf = design_kcf(system, cost, graph, 20, variant="stale")  # the 0.1 KCF: no analytic cost
    assert "no analytic cost (Monte Carlo)" in _cells(DesignReprMixin._repr_html_(kcf))


def test_monte_carlo_and_cost_curves_html(platoon):
    system, cost, graph = platoon
    d = design_mtmse(system, cost, graph, horizon=10)
    mc = monte_carlo({"mtmse": d}, 10, n_runs=50, rng=3)["mtmse"]
    cells = _cells(mc._repr_html_())
    lo, hi = mc.ci95
    assert [format_value(v) for v in (mc.total_mean, lo, hi)] == cells[cells.index("mtmse") + 3 : cells.index("mtmse") + 6]
    cc = CostCurves.from_designs({"mtmse": d}, title="platoon")
    cells = _cells(cc._repr_html_())
    assert format_value(d.total_cost) in cells and "analytic" in cells and "platoon" in cc._repr_html_()


def test_sweep_result_html():
    rows = [
        {"cost.lambda": lam, "point_id": f"p{k}", "point_index": k, "estimator": e, "method": "analytic", "total_cost": c}
        for k, lam in enumerate((1.0, 10.0))
        for e, c in (("mtmse", 10.0 * (k + 1)), ("mmse", 12.5 * (k + 1)))
    ]
    res = SweepResult(tuple(rows), ("cost.lambda",))
    html = res._repr_html_()
    assert "2 points × 2 estimators" in html
    cells = _cells(html)
    assert cells[:6] == ["cost.lambda", "estimator", "method", "total_cost", "ci95_low", "ci95_high"]
    assert cells[6:10] == ["1", "mtmse", "analytic", "10"] and "25" in cells


def test_experiment_result_html_and_plot(tmp_path):
    res = experiments.run("table1", tmp_path, quick=True)
    html = res._repr_html_()
    assert res.published_columns == ["J_T*/lambda (paper, Table I)"]
    assert html.count('class="teamkf-published"') == 1 + len(res.rows)
    ax = res.plot()
    img = np.asarray(ax.get_images()[0].get_array())
    assert img.ndim == 3 and img.shape[0] > 50  # the PNG the experiment wrote
    bare = experiments.run("fig1", None, quick=True)
    assert bare.figures == []
    with pytest.raises(ArgumentError, match="figures: experiment 'fig1' wrote none"):
        bare.plot()


def test_bulk_filter_html_and_plot():
    from teamkf.estimators.bulk import exact_bulk_filter, finite_memory_filter
    from teamkf.models import PopulationModel

    model = PopulationModel(n_agents=1000, a=2.5, f=2.0)
    for flt in (exact_bulk_filter(model, 50), finite_memory_filter(model, 50, memory=3)):
        cells = _cells(flt._repr_html_())
        assert type(flt).__name__ in cells and "1000" in cells and "50" in cells
        assert format_value(float(flt.covariances.error_variance[-1])) in cells
        ax = flt.plot()
        np.testing.assert_allclose(ax.get_lines()[1].get_ydata(), flt.covariances.error_variance)


def test_lqg_design_html():
    from teamkf.control.lqg import design_lqg
    from teamkf.experiments.lqg import problem

    d = design_lqg(problem(1.0), 10)
    cells = _cells(d._repr_html_())
    assert "Theorem 4 (MTMSE)" in cells and format_value(d.cost) in cells and "10" in cells


# --- one colour per family, Monte Carlo bands, readable structure plots -------------------------------
def test_one_colour_per_family_everywhere():
    from matplotlib.colors import to_hex

    from teamkf.plotting import family_color, stage_cost_axes

    system, cost, graph = LinearGaussianSystem.platoon(4), TeamCost.platoon(4, 10.0), CommGraph.line(4, delay=1)
    designs = [
        design_mtmse(system, cost, graph, horizon=10),
        design_mmse(system, cost, graph, horizon=10),
        design_centralized(system, cost, horizon=10),
    ]
    ax = stage_cost_axes(designs)
    assert {line.get_label(): to_hex(line.get_color()) for line in ax.lines} == {n: family_color(n).lower() for n in ("mtmse", "mmse", "centralized")}
    rows = tuple(
        {
            "graph.delay": dl,
            "point_id": str(dl),
            "point_index": dl,
            "estimator": e,
            "method": "analytic",
            "total_cost": float(dl + k),
            "ci95_low": None,
            "ci95_high": None,
        }
        for dl in (1, 2, 3)
        for k, e in enumerate(("mmse", "mtmse"))  # another order than above: the colours follow the name, not the order
    )
    ax2 = SweepResult(rows, ("graph.delay",)).plot()
    assert {line.get_label(): to_hex(line.get_color()) for line in ax2.lines} == {n: family_color(n).lower() for n in ("mmse", "mtmse")}
    assert [t.get_text() for t in ax2.get_xticklabels()] == ["1", "2", "3"], "an integer axis gets integer ticks"
    assert family_color("my_own_filter") == family_color("my_own_filter") and family_color("my_own_filter") not in {
        family_color(n) for n in ("mtmse", "mmse", "kcf")
    }


def test_evaluate_plot_draws_the_monte_carlo_means(tmp_path):
    from teamkf.cli import main

    a, b = tmp_path / "a.png", tmp_path / "b.png"
    assert main(["--quiet", "evaluate", "platoon-4", "--plot", str(a)]) == 0
    assert main(["--quiet", "evaluate", "platoon-4", "--monte-carlo", "50", "--seed", "1", "--plot", str(b)]) == 0
    assert a.read_bytes() != b.read_bytes(), "--monte-carlo must show in the plot"
    mc = monte_carlo(
        {"mtmse": design_mtmse(LinearGaussianSystem.platoon(4), TeamCost.platoon(4, 100.0), CommGraph.line(4, delay=1), horizon=10)}, 10, 50, rng=1
    )
    from teamkf.plotting import stage_cost_axes

    ax = stage_cost_axes([], monte_carlo=mc)
    assert [line.get_label() for line in ax.lines] == ["mtmse (Monte Carlo, 50 runs)"] and len(ax.collections) == 1  # the 95 % band


@pytest.mark.parametrize("n", [6, 20])
def test_information_plot_fits_a_page(n):
    axs = InformationStructure.own_window(n, common_lag=2).plot()
    fig = np.ravel(axs)[0].figure
    width, height = fig.get_size_inches()
    assert width <= 16 and height <= 12, f"n = {n}: {width:.1f} x {height:.1f} in"
    assert len([a for a in fig.axes if a.get_visible() and a.has_data()]) == n
