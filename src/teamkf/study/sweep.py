"""Parameter sweeps: serial or on Dask, written point by point, resumable.

A sweep file (TOML, or JSON by its ``.json`` extension) names a base scenario,
a grid of dotted keys, the estimators, the Monte Carlo runs and a seed; the
keys are a contract (``design/scenario-and-cli.md``):

=============  ================================================================
key            meaning
=============  ================================================================
scenario       base scenario: a path relative to the sweep file's folder, or
               the name of a packaged scenario (``"platoon-4"``) (required)
runs           Monte Carlo runs per point: 0 (analytic costs only, the
               default) or at least 2 (needs a finite horizon)
seed           integer >= 0 (default 0); every point gets its own seed from it
estimators     optional list of names; default: the scenario's ``estimators``
[grid]         dotted key -> non-empty list of values (required, at least one
               key); every combination is one point, in the order of the
               file (the last key varies fastest)
name           optional name of the sweep (default: the file's stem)
description    optional free text
=============  ================================================================

Grid keys are dotted paths into the scenario (``"cost.lambda"``,
``"graph.delay"``, ``"horizon"``, ``"agents[2].R"``; see
:func:`teamkf.study.scenario.set_dotted`). Quote them in TOML (``"cost.lambda" =
[...]``); unquoted dotted keys (``cost.lambda = [...]``) make nested tables,
which are read as the same dotted keys. One special key:

``system.A_scale``
    multiplies the scenario's ``A`` (every matrix of a time-varying ``A``) by
    the value, e.g. ``"system.A_scale" = [0.9, 1.0, 1.1]``; applied after the
    other keys of the point.

The values of one key must be of one type (numbers, which may mix integers
and floats and are then all stored as floats; strings; booleans; or lists /
tables, which are stored as JSON text). Everything is checked before anything
is computed or written: unknown sweep keys, an empty grid or value list,
values that are not lists, wrong types of ``runs`` / ``seed`` /
``estimators``, and every grid point is applied to the base scenario
(:meth:`~teamkf.study.scenario.Scenario.updated`), so an unknown dotted key or a
bad value is a :class:`~teamkf.exceptions.ScenarioError` naming the key.

Points and seeds
----------------
Point ``k`` of the Cartesian product (in grid order) has

- ``point_id``: the first 12 hex digits of the SHA-256 of the canonical JSON
  (sorted keys, no spaces) of its parameters ``{key: value}``; stable across
  runs, machines and grid orders;
- ``seed``: the sweep's ``seed`` itself for point 0, and
  ``SeedSequence(seed).spawn(n_points)[k].generate_state(1, uint64)[0] >> 1``
  for point k >= 1 (a 63-bit integer, so that it fits a signed Parquet
  column), passed to :func:`~teamkf.study.evaluation.evaluate`. A point's
  numbers therefore depend only on the sweep file and ``k``, never on the
  worker that ran it or on the order in which points finish: serial and Dask
  runs give identical numbers. ``teamkf evaluate`` on the point's scenario
  with ``--monte-carlo RUNS --seed <point seed>`` reproduces them; a one-point
  sweep with ``runs = R, seed = S`` gives exactly the numbers of
  ``teamkf evaluate --monte-carlo R --seed S``.

Results folder
--------------
:func:`run_sweep` writes the results into a folder ``OUT`` (e.g.
``results.parquet``) that Parquet readers treat as one dataset
(``pandas.read_parquet(OUT)``, ``pyarrow.parquet.read_table(OUT)``,
:meth:`SweepResult.load(OUT) <teamkf.study.results.SweepResult.load>`):

- ``part-<point_id>.parquet``: the rows of one point (one per estimator),
  written by the driver as soon as the point finishes, under a temporary
  name that is then renamed (``os.replace``), so a crash never leaves a
  half-written part;
- ``_sweep.json``: the sweep that wrote the folder (ignored by Parquet
  readers). ``resume`` checks it, so results of another sweep are never mixed
  in, and skips the points whose part exists.

Columns: one per grid key, then ``point_id``, ``point_index``, ``estimator``,
``method``, ``total_cost`` (finite horizon) or ``average_cost`` (steady
state), ``ci95_low``, ``ci95_high`` (null for analytic values), with Monte
Carlo runs ``mc_cost``, ``mc_ci95_low``, ``mc_ci95_high`` (the simulated cost
of the analytic estimators), then ``runs``, ``seed`` (the point's seed),
``diverged``, ``non_finite`` (null, or a JSON object naming each column whose
number is not finite, ``{"total_cost": "inf"}``, as ``teamkf evaluate --json``
marks them), ``sweep_seed`` (the sweep file's) and ``teamkf_version``.

Schedulers
----------
``"local"`` (default)
    an embedded ``dask.distributed.LocalCluster`` with one single-threaded
    worker process per available core (``n_workers``), made by
    :func:`local_cluster`: the workers get ``OMP_NUM_THREADS =
    OPENBLAS_NUM_THREADS = MKL_NUM_THREADS = 1`` so that they do not compete
    for cores (the points are the parallelism), and not Dask's
    ``MALLOC_TRIM_THRESHOLD_`` (about 40 % slower points).
an address (``"tcp://host:8786"``), a ``Client`` or a cluster object
    an existing Dask cluster; its workers need teamkf installed.
``"serial"``
    in-process, no Dask.

On Dask the validated sweep spec is scattered to every worker once and every
point is one task (``client.submit(_run_spec_point, evaluate_point, spec,
index, pure=False, retries=3)``: the worker builds the point's scenario from
the spec, so the client ships a point index, not a scenario), collected with
``as_completed``: if a worker dies, the scheduler runs its tasks again
elsewhere, and the driver, not the workers, writes the results.

Examples
--------
>>> from teamkf.study.sweep import sweep_from_dict
>>> spec = sweep_from_dict({"scenario": "platoon-4", "seed": 1,
...                         "grid": {"cost.lambda": [1, 10.5], "graph.delay": [1, 2]}})
>>> spec.n_points, spec.grid["cost.lambda"]
(4, (1.0, 10.5))
>>> [(p.index, p.params) for p in spec.points[:2]]
[(0, {'cost.lambda': 1.0, 'graph.delay': 1}), (1, {'cost.lambda': 1.0, 'graph.delay': 2})]
>>> spec.scenario_for(spec.points[1]).graph.edges[0]
(0, 1, 2)
"""

from __future__ import annotations

import json
import math
import time
import uuid
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from .. import _validation as V
from .._blas import single_thread_blas
from .._progress import bar as _progress_bar
from .._version import __version__
from ..exceptions import TeamkfError
from ..simulation.parallel import WORKER_ENV, _cpu_count, _open_client, local_cluster, with_plugins  # noqa: F401  (public here since 0.1)
from .evaluate import evaluate_point, is_analytic  # noqa: F401  (evaluate_point is looked up by _module_evaluate)
from .outputs import write_atomic
from .results import MANIFEST_NAME, SweepError, SweepResult, load_results
from .scenario import Scenario

__all__ = [
    "SweepSpec",
    "SweepPoint",
    "SweepError",
    "load_sweep",
    "sweep_from_dict",
    "apply_point",
    "run_sweep",
    "run_point",
    "point_id",
    "local_cluster",
    "A_SCALE",
    "WORKER_ENV",
]

from .sweep_spec import (  # noqa: F401  (public here: the sweep file's parser lives in sweep_spec)
    _FORMAT,
    _MAX_SEED,
    A_SCALE,
    SweepPoint,
    SweepSpec,
    _canonical,
    apply_point,
    load_sweep,
    point_id,
    sweep_from_dict,
)

# ---------------------------------------------------------------------------
# running
# ---------------------------------------------------------------------------
#: the unit of work of a point: (scenario, estimators, runs, seed) -> rows
PointFunction = Callable[[Scenario, Sequence[str], int, int], list[dict[str, Any]]]


def run_sweep(
    spec: SweepSpec | str | Path,
    out: str | Path,
    scheduler: Any = "local",
    *,
    resume: bool = False,
    progress: bool = True,
    n_workers: int | None = None,
    retries: int = 3,
    evaluate: PointFunction | None = None,
    on_point_done: Callable[[SweepPoint, list[dict[str, Any]]], None] | None = None,
) -> SweepResult:
    """Evaluate every grid point and write each point's rows into ``out`` as soon as it finishes.

    Parameters
    ----------
    spec : SweepSpec, or the path of a sweep file
    out : results folder (see the module docstring); must not exist (or be
        empty) unless ``resume``
    scheduler : ``"local"`` (an embedded Dask LocalCluster, the default),
        ``"serial"`` (in-process), a Dask scheduler address, a
        ``distributed.Client`` or a cluster object
    resume : keep the points already in ``out`` (written by the same sweep)
        and compute only the missing ones
    progress : show a progress bar on stderr (tqdm when installed, else a
        text line): points done, rate and time left
    n_workers : worker processes of the embedded LocalCluster (default: one
        per available core)
    retries : Dask retries of a point whose function raised (a point lost
        with a dead worker is rerun by the scheduler in any case)
    evaluate : the point function (default
        :func:`~teamkf.study.evaluate.evaluate_point`); on Dask it must
        be importable on the workers
    on_point_done : called as ``on_point_done(point, rows)`` in the driver
        after each point's part is written

    Returns
    -------
    SweepResult
        Every row in ``out`` (including resumed points), in grid order.

    Raises
    ------
    SweepError
        If ``out`` holds results and ``resume`` is False, holds results of
        another sweep, or a point fails (the finished points are kept).
    OptionalDependencyError
        Without pyarrow (and dask.distributed, except for ``"serial"``).
    """
    if not isinstance(spec, SweepSpec):
        spec = load_sweep(spec)
    out = Path(out)
    fn: PointFunction = evaluate if evaluate is not None else _module_evaluate()
    serial = isinstance(scheduler, str) and scheduler == "serial"
    pa = V.require("pyarrow", "dask")
    V.require("pyarrow.parquet", "dask")
    if not serial:
        V.require("dask.distributed", "dask")
    if n_workers is not None:
        n_workers = V.positive_int(n_workers, "n_workers")

    done = _check_out(spec, out, resume)
    created = not out.exists()  # a folder this run makes is removed again when it ends with no point in it
    points = spec.points
    writer = _Writer(spec, out, pa)
    done = _readable_parts(out, done, writer.schema)
    todo = [p for p in points if p.point_id not in done]
    bar = _progress_bar(len(points), initial=len(points) - len(todo), enabled=False, desc=f"sweep {spec.name}", unit="point")
    n_ok = 0

    def start() -> None:
        nonlocal bar
        writer.create()
        bar = _progress_bar(
            len(points), initial=len(points) - len(todo), enabled=None if progress else False, desc=f"sweep {spec.name}", unit="point"
        )

    def finish(p: SweepPoint, rows: list[dict[str, Any]]) -> None:
        nonlocal n_ok
        writer.write(p, rows)
        n_ok += 1
        bar.update()
        if on_point_done is not None:
            on_point_done(p, rows)

    def failed(p: SweepPoint, exc: BaseException) -> SweepError:
        what = str(exc) if isinstance(exc, TeamkfError) else f"{type(exc).__name__}: {exc}"
        n_kept = len(points) - len(todo) + n_ok
        if n_kept == 0 and created:
            return SweepError(f"grid point {p.index} ({p.describe()}) failed: {what}; nothing was written")
        return SweepError(
            f"grid point {p.index} ({p.describe()}) failed: {what}; the {n_kept} finished points are kept in "
            f"{out}; fix the problem and run again with --resume (resume=True)"
        )

    try:
        if todo and serial:
            start()
            for p in todo:
                sc = spec.scenario_for(p)
                try:
                    rows = run_point(fn, sc, spec.estimators, spec.runs, p.seed)
                except Exception as exc:
                    raise failed(p, exc) from exc
                finish(p, rows)
        elif todo:
            client, owned = _open_client(scheduler, n_workers)
            futures: list[Any] = []
            try:
                from distributed import as_completed

                start()
                token = uuid.uuid4().hex[:8]
                by_key: dict[Any, SweepPoint] = {}
                # the validated spec goes to every worker once; a task is (spec, point index): the worker
                # builds the point's scenario, the client neither rebuilds nor ships one per point
                [fspec] = client.scatter([spec], broadcast=True, hash=False)
                task = with_plugins(_run_spec_point, client)  # a worker holding another version of a plug-in refuses
                for p in todo:
                    f = client.submit(
                        task,
                        fn,
                        fspec,
                        p.index,
                        pure=False,
                        retries=retries,
                        key=f"teamkf-sweep-{p.point_id}-{token}",
                    )
                    futures.append(f)
                    by_key[f.key] = p
                for f in as_completed(futures):
                    p = by_key[f.key]
                    try:
                        rows = f.result()
                    except Exception as exc:
                        raise failed(p, exc) from exc
                    finish(p, rows)
            finally:
                pending = [f for f in futures if not f.done()]
                if pending:
                    try:
                        client.cancel(pending)
                    except Exception:  # pragma: no cover - cluster already gone
                        pass
                for obj in owned:
                    try:
                        obj.close()
                    except Exception:  # pragma: no cover - best effort on shutdown
                        pass
    except BaseException:  # a failure or Ctrl-C before the first point: no empty results folder left behind
        if created and n_ok == 0:
            _remove_empty(out)
        raise
    finally:
        bar.close()

    res = load_results(out) if out.exists() else SweepResult((), spec.grid_keys, path=out)
    return SweepResult(res.rows, res.grid_keys, path=out, n_computed=n_ok, n_resumed=len(points) - len(todo), info=res.info)


def _remove_empty(out: Path) -> None:
    """Remove a results folder that holds nothing but its manifest and temporary parts (what an interrupted first point leaves)."""
    if not out.is_dir():
        return
    entries = list(out.iterdir())
    if all(e.name == MANIFEST_NAME or e.name.startswith(".") for e in entries) and all(e.is_file() for e in entries):
        for e in entries:
            e.unlink(missing_ok=True)
        out.rmdir()


def run_point(fn: PointFunction, scenario: Scenario, estimators: Sequence[str], runs: int, seed: int) -> list[dict[str, Any]]:
    """``fn(scenario, estimators, runs, seed)`` with BLAS and OpenMP limited to one thread.

    This is the task of a point, serial or on a Dask worker. OpenBLAS and MKL
    sum in a different order with a different number of threads (differences
    of about 1e-12 relative), so every point runs single-threaded, wherever it
    runs: serial and Dask runs then give identical numbers. Uses threadpoolctl
    (in the ``dask`` extra); without it the threads are left as they are.
    """
    with _single_thread():
        return fn(scenario, estimators, runs, seed)


def _run_spec_point(fn: PointFunction, spec: SweepSpec, index: int) -> list[dict[str, Any]]:
    """The Dask task of grid point ``index``: its scenario is built on the worker from the shared spec."""
    p = spec.points[index]
    return run_point(fn, spec.scenario_for(p), spec.estimators, spec.runs, p.seed)


def _single_thread() -> Any:
    return single_thread_blas()


def _module_evaluate() -> PointFunction:
    # looked up at call time, so that a replaced ``sweep.evaluate_point`` is used
    return globals()["evaluate_point"]  # type: ignore[no-any-return]


def _check_out(spec: SweepSpec, out: Path, resume: bool) -> set[str]:
    """The ids of the points already in ``out``; refuses to mix results. Writes nothing."""
    if not out.exists():
        parent = out.parent if str(out.parent) else Path(".")
        if not parent.is_dir():
            raise SweepError(f"{out}: the folder {str(parent)!r} does not exist; create it first (teamkf does not create folders) or fix --out")
        return set()
    if not out.is_dir():
        raise SweepError(f"{out}: exists and is a file; sweep results are a folder of Parquet parts, choose another --out")
    entries = list(out.iterdir())
    if not entries:
        return set()
    manifest = out / MANIFEST_NAME
    if not manifest.is_file():
        raise SweepError(f"{out}: exists and is not a teamkf sweep results folder (no {MANIFEST_NAME}); choose another --out")
    if not resume:
        raise SweepError(f"{out}: results already exist; pass --resume (resume=True) to continue this sweep, or choose another --out")
    foreign = [
        e.name
        for e in entries
        if e.name != MANIFEST_NAME and not e.name.startswith(".") and not (e.name.startswith("part-") and e.name.endswith(".parquet"))
    ]
    if foreign:
        raise SweepError(
            f"{out}: expected only Parquet parts and {MANIFEST_NAME}, found {foreign[0]!r}"
            f"{f' and {len(foreign) - 1} more entries' if len(foreign) > 1 else ''} (no sweep writes it; Parquet readers would fail on it); "
            "move it out of the results folder, then --resume"
        )
    try:
        info = json.loads(manifest.read_text(encoding="utf-8"))
        theirs = info["fingerprint"]
    except (ValueError, KeyError, TypeError):
        raise SweepError(f"{manifest}: unreadable sweep description; choose another --out") from None
    mine = spec.fingerprint()
    if _canonical(theirs) != _canonical(mine):
        diff = [k for k in mine if _canonical(theirs.get(k) if isinstance(theirs, dict) else None) != _canonical(mine[k])]
        raise SweepError(
            f"{out}: holds results of a different sweep ({', '.join(diff) or 'format'} differ); "
            "choose another --out, or delete that folder to start again"
        )
    ids = {p.point_id for p in spec.points}
    return {e.name[len("part-") : -len(".parquet")] for e in entries if e.name.startswith("part-") and e.name.endswith(".parquet")} & ids


def _readable_parts(out: Path, done: set[str], schema: Any) -> set[str]:
    """The parts of ``done`` that read back as this sweep wrote them (its columns and types, at least one row);
    a truncated or foreign part is recomputed (overwritten), with one ``teamkf: warning:`` line."""
    import sys

    import pyarrow.parquet as pq

    ok = set()
    for pid in sorted(done):
        part = out / f"part-{pid}.parquet"
        try:
            meta = pq.read_metadata(part)
            found = meta.schema.to_arrow_schema()
            why = None if found.remove_metadata().equals(schema.remove_metadata()) else "its columns or their types differ from this sweep's"
            if why is None and meta.num_rows == 0:
                why = "it has no rows"
        except Exception as exc:  # noqa: BLE001 - pyarrow's own error types (ArrowInvalid, OSError)
            why = f"not readable as Parquet ({type(exc).__name__}: {' '.join(str(exc).split())[:120]})"
        if why is None:
            ok.add(pid)
        else:
            print(f"teamkf: warning: sweep part {part}: {why}; recomputing that grid point", file=sys.stderr, flush=True)
    return ok


class _Writer:
    """Writes one Parquet part per point, atomically (:func:`teamkf.study.outputs.write_atomic`: a temporary name, then ``os.replace``)."""

    def __init__(self, spec: SweepSpec, out: Path, pa: Any) -> None:
        self.spec, self.out, self.pa = spec, out, pa
        self.version = __version__
        types = {"int": pa.int64(), "float": pa.float64(), "string": pa.string(), "bool": pa.bool_(), "json": pa.string()}
        fields = [pa.field(k, types[spec.kinds.get(k, "json")]) for k in spec.grid]
        fields += [
            pa.field("point_id", pa.string()),
            pa.field("point_index", pa.int64()),
            pa.field("estimator", pa.string()),
            pa.field("label", pa.string()),
            pa.field("method", pa.string()),
        ]
        fields += [pa.field(k, pa.float64()) for k in spec.cost_keys]
        fields += [pa.field("ci95_low", pa.float64()), pa.field("ci95_high", pa.float64())]
        if spec.runs and any(is_analytic(e) for e in spec.estimators):
            fields += [pa.field(k, pa.float64()) for k in ("mc_cost", "mc_ci95_low", "mc_ci95_high")]
        fields += [
            pa.field("runs", pa.int64()),
            pa.field("seed", pa.int64()),
            pa.field("diverged", pa.bool_()),
            pa.field("cost_links", pa.string()),  # "perfect" | "lossy" | "assumed": the links the cost is under (teamkf.study.report)
            pa.field("links", pa.string()),  # the point's link model in one line ("perfect", "p_drop 0.3 on every edge", ...)
            pa.field("non_finite", pa.string()),  # JSON {column: "inf" | "-inf" | "nan"} naming the non-finite numbers; null when all are finite
            pa.field("sweep_seed", pa.int64()),
            pa.field("teamkf_version", pa.string()),
        ]
        meta = {"teamkf.grid_keys": json.dumps(list(spec.grid)), "teamkf.sweep": spec.name}
        self.schema = pa.schema(fields, metadata=meta)

    def create(self) -> None:
        """Create the folder and its ``_sweep.json`` (kept as is when resuming)."""
        self.out.mkdir(exist_ok=True)  # the results folder itself; a missing parent was refused by _check_out
        for stale in [*self.out.glob(".part-*.tmp*"), *self.out.glob(f".{MANIFEST_NAME}.*tmp*")]:  # left by a killed writer
            stale.unlink(missing_ok=True)
        manifest = self.out / MANIFEST_NAME
        if manifest.exists():
            return
        spec = self.spec
        info = {
            "format": _FORMAT,
            "name": spec.name,
            "description": spec.description,
            "sweep_file": spec.source,
            "scenario": spec.scenario,
            "grid_keys": list(spec.grid),
            "grid_kinds": dict(spec.kinds),
            "estimators": list(spec.estimators),
            "cost_keys": list(spec.cost_keys),
            "n_points": spec.n_points,
            "teamkf_version": self.version,
            "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
            "fingerprint": spec.fingerprint(),
        }
        text = json.dumps(info, indent=2, allow_nan=True) + "\n"
        write_atomic(manifest, lambda fh: fh.write(text), text=True)

    def records(self, p: SweepPoint, rows: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
        spec = self.spec
        base: dict[str, Any] = {}
        for k in spec.grid:
            v = p.params[k]
            base[k] = _canonical(v) if spec.kinds.get(k) == "json" else v
        recs = []
        for r in rows:
            rec = dict(base)
            rec.update({"point_id": p.point_id, "point_index": p.index})
            for name in self.schema.names:
                if name in r and name not in base and name not in ("point_id", "point_index"):
                    rec[name] = r[name]
            bad = {k: str(float(v)) for k, v in rec.items() if isinstance(v, (float, np.floating)) and not math.isfinite(v)}
            rec["non_finite"] = json.dumps(bad, sort_keys=True) if bad else None  # as teamkf evaluate --json and sweep --json mark them
            rec.setdefault("runs", spec.runs)
            rec["seed"] = p.seed  # the point's seed: teamkf evaluate --seed <it> repeats the point
            rec["sweep_seed"] = spec.seed
            rec["teamkf_version"] = self.version
            recs.append(rec)
        return recs

    def write(self, p: SweepPoint, rows: Sequence[Mapping[str, Any]]) -> Path:
        import pyarrow.parquet as pq

        table = self.pa.Table.from_pylist(self.records(p, rows), schema=self.schema)
        final = self.out / f"part-{p.point_id}.parquet"
        write_atomic(final, lambda fh: pq.write_table(table, fh))
        return final
