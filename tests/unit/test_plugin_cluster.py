"""Plug-ins on a running Dask cluster: a plug-in's identity is its module name and the sha256 of its source.

A worker that holds another version of a plug-in (the file was edited since the last run) is updated from
the shipped source, so the edited plug-in's numbers come back, never the old file's; where it cannot be
updated (another family of the same name there, another version loaded by a concurrent run) the run is
refused in one line naming the worker, the scheduler and the files and hashes. One real process-based
LocalCluster (one worker) for the module.
"""

from __future__ import annotations

import importlib.util
import json
import logging
from pathlib import Path

import numpy as np
import pytest

import teamkf
from teamkf.cli import main
from teamkf.estimators import registry
from teamkf.exceptions import ArgumentError

pytestmark = pytest.mark.skipif(importlib.util.find_spec("distributed") is None, reason="needs the dask extra")

ROOT = Path(__file__).resolve().parents[2]
FAMILY = "scaled_kf"


def plugin_source(scale: float) -> str:
    """examples/custom_family.py as family ``scaled_kf`` (no replace=True), its estimates multiplied by ``scale``."""
    text = (ROOT / "examples" / "custom_family.py").read_text()
    text = text.replace('name="avg_kf"', f'name="{FAMILY}"').replace('estimator="avg_kf"', f'estimator="{FAMILY}"')
    text = text.replace("    replace=True,\n", "")
    text = text.replace("z = np.mean(views, axis=0) @", f"z = {scale!r} * np.mean(views, axis=0) @")
    assert f"{scale!r} * np.mean" in text and "replace=True" not in text
    return text


def scenario(tmp_path: Path) -> Path:
    p = tmp_path / "scaled.json"
    p.write_text(
        json.dumps(
            {
                "name": "scaled",
                "horizon": 8,
                "system": {"A": (0.9 * np.eye(3)).tolist(), "Q": 1.0, "Sigma_x": 1.0},
                "agents": [{"C": np.eye(3).tolist(), "R": 0.2} for _ in range(3)],
                "graph": {"kind": "ring", "delay": 1},
                "cost": {"kind": "mse"},
                "estimators": [FAMILY, "centralized"],
            }
        )
    )
    return p


@pytest.fixture(scope="module")
def cluster():
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(
        n_workers=1, threads_per_worker=1, processes=True, host="127.0.0.1", dashboard_address=None, silence_logs=logging.ERROR
    ) as c:
        with distributed.Client(c) as client:
            worker = next(iter(client.scheduler_info()["workers"]))
        yield c.scheduler_address, worker


@pytest.fixture()
def clean():
    """Forget every plug-in module a test loads (here and in the registry)."""
    before = {name for name, _, _ in registry.loaded_plugins()}
    yield
    for name, _, _ in registry.loaded_plugins():
        if name not in before:
            registry._unload_plugin(name)
    teamkf.unregister_family(FAMILY)


def mc_cost(capsys, plugin: Path, scen: Path, scheduler: str | None) -> float:
    argv = ["--plugin", str(plugin), "evaluate", str(scen), "--json", "--monte-carlo", "24", "--seed", "3", "--quiet"]
    rc = main(argv + (["--scheduler", scheduler] if scheduler else []))
    out = capsys.readouterr()
    assert rc == 0, out.err
    return float(json.loads(out.out)["estimators"][FAMILY]["total_cost"])  # a Monte Carlo family: its J_T is the Monte Carlo mean


def test_a_plugin_edited_in_place_gives_the_new_result_on_the_cluster(cluster, tmp_path, capsys, clean):
    address, _ = cluster
    plug, scen = tmp_path / "scaled.py", scenario(tmp_path)
    plug.write_text(plugin_source(1.0))
    old = mc_cost(capsys, plug, scen, address)
    assert old == mc_cost(capsys, plug, scen, None)  # the cluster gives the serial numbers
    plug.write_text(plugin_source(1.5))  # edited in place: the worker still holds the old module
    new_serial = mc_cost(capsys, plug, scen, None)
    assert new_serial != old
    assert mc_cost(capsys, plug, scen, address) == new_serial  # never the old file's result
    held = registry.plugin_identities()["teamkf_plugin_scaled"]
    assert held == registry._sha256(plugin_source(1.5)) and len(held) == 64


def test_the_same_family_under_another_file_name_is_a_clear_refusal(cluster, tmp_path, capsys, clean):
    address, worker = cluster
    first, scen = tmp_path / "scaled.py", scenario(tmp_path)
    first.write_text(plugin_source(1.0))
    mc_cost(capsys, first, scen, address)  # the worker now holds teamkf_plugin_scaled with family scaled_kf
    registry._unload_plugin("teamkf_plugin_scaled")  # a fresh driver process: only the renamed copy
    other = tmp_path / "other.py"
    other.write_text(plugin_source(1.5))
    argv = ["--plugin", str(other), "evaluate", str(scen), "--json", "--monte-carlo", "24", "--seed", "3", "--scheduler", address]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("teamkf: error: ")
    assert f"a family called '{FAMILY}' is already registered by plug-in {first.resolve()}" in err
    assert f"sha256 {registry._sha256(plugin_source(1.0))[:12]}" in err and f"sha256 {registry._sha256(plugin_source(1.5))[:12]}" in err
    assert f"on the Dask worker {worker} of the cluster at {address}" in err and str(other.resolve()) in err


def test_the_same_family_from_two_files_in_one_process_names_the_first(tmp_path, clean):
    a, b = tmp_path / "scaled.py", tmp_path / "copy.py"
    a.write_text(plugin_source(1.0))
    b.write_text(plugin_source(2.0))
    teamkf.load_plugin(str(a))
    with pytest.raises(ArgumentError) as info:
        teamkf.load_plugin(str(b))
    msg = str(info.value)
    assert f"already registered by plug-in {a.resolve()} (sha256 {registry._sha256(a.read_text())[:12]})" in msg
    assert f"plug-in {b.resolve()} (sha256 {registry._sha256(b.read_text())[:12]}) registers it again" in msg
    assert "Dask" not in msg and "teamkf_plugin_copy" not in registry.plugin_identities()


def test_a_task_on_a_worker_holding_another_version_is_refused(cluster, tmp_path, clean):
    """A concurrent run replaced the plug-in on the worker after this run loaded its own: the task refuses."""
    from teamkf.simulation.parallel import _open_client, with_plugins

    address, worker = cluster
    plug = tmp_path / "scaled.py"
    plug.write_text(plugin_source(1.0))
    teamkf.load_plugin(str(plug))
    client, owned = _open_client(address, None)
    try:
        name, path, _ = registry.loaded_plugins()[-1]
        client.run(registry.load_plugins_into, [(name, path, plugin_source(3.0))])  # what another run would do
        task = with_plugins(teamkf.families, client)
        with pytest.raises(ArgumentError) as info:
            client.submit(task, pure=False).result()
    finally:
        for obj in owned:
            obj.close()
    msg = str(info.value)
    assert f"the Dask worker {worker} of the cluster at {address} holds plug-in {plug.resolve()}" in msg
    assert registry._sha256(plugin_source(3.0))[:12] in msg and registry._sha256(plugin_source(1.0))[:12] in msg
    assert "never runs a stale plug-in" in msg


def test_identities_ride_with_tasks_only_when_plugins_are_loaded():
    from teamkf.simulation.parallel import _WithPlugins, with_plugins

    fn = with_plugins(len, object())
    assert (fn is len) == (not registry.plugin_identities())
    if registry.plugin_identities():
        assert isinstance(fn, _WithPlugins)
