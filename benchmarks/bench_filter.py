"""`teamkf filter` on a long log: 10^6 steps of the 4-vehicle platoon (4 x 10^6 rows), steady-state gains.

    PYTHONPATH=src python3 benchmarks/bench_filter.py [--steps 1000000] [--format parquet|csv] [--keep DIR]

Writes a measurement log (and the true states) of the platoon-4-steady scenario,
simulated with a seed, then runs ``teamkf filter platoon-4-steady --measurements
LOG --truth X --out Z`` in a child process (every family with a steady-state
form: MTMSE, MMSE, centralized) and reports its wall time and peak resident
memory (``ru_maxrss`` of the child). The targets: < 60 s and < 1 GiB.

As a baseline in the same run, the streaming filter's estimates on the first
--check steps are compared with the online agents' (the Monte Carlo runtime
path) and their time per step is reported: the ratio is what the steady-state
LTI forms buy.
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def write_log(path: Path, xpath: Path, steps: int, fmt: str, *, seed: int = 12, chunk: int = 100_000) -> None:
    """Simulate the platoon in chunks (bounded memory) and write long-form rows step, agent, y0..y3."""
    import pyarrow as pa
    import pyarrow.csv as pacsv
    import pyarrow.parquet as pq

    from teamkf.study.scenario import load_packaged

    sc = load_packaged("platoon-4-steady")
    sys_ = sc.system
    A = sys_.A_at(0)
    n, dx = sys_.n_agents, sys_.dx
    rng = np.random.default_rng(seed)
    Lx = np.linalg.cholesky(sys_.Sigma_x)
    Lq = np.linalg.cholesky(sys_.Q_at(0))
    Lr = [np.linalg.cholesky(sys_.R_at(i, 0)) for i in range(n)]
    x = Lx @ rng.standard_normal(dx)
    w = wx = None
    try:
        for k0 in range(0, steps, chunk):
            B = min(chunk, steps - k0)
            X = np.empty((B, dx))
            W = rng.standard_normal((B, dx)) @ Lq.T
            for t in range(B):
                X[t] = x
                x = A @ x + W[t]
            Ys = [X @ sys_.C_at(i, 0).T + rng.standard_normal((B, sys_.dy[i])) @ Lr[i].T for i in range(n)]
            Yr = np.stack(Ys, axis=1).reshape(B * n, -1)
            cols = {"step": np.repeat(np.arange(k0, k0 + B, dtype=np.int64), n), "agent": np.tile(np.arange(n, dtype=np.int64), B)}
            cols.update({f"y{c}": Yr[:, c] for c in range(Yr.shape[1])})
            t = pa.table(cols)
            tx = pa.table({"step": np.arange(k0, k0 + B, dtype=np.int64), **{f"x{c}": X[:, c] for c in range(dx)}})
            if w is None:
                w = pacsv.CSVWriter(str(path), t.schema) if fmt == "csv" else pq.ParquetWriter(str(path), t.schema)
                wx = pq.ParquetWriter(str(xpath), tx.schema)
            w.write_table(t)
            wx.write_table(tx)
    finally:
        if w is not None:
            w.close()
            wx.close()


def baseline(check: int) -> tuple[float, float, float]:
    """Streaming vs the online agents on the first `check` steps: max |difference|, seconds per step of each."""
    import io

    import pandas as pd

    from teamkf.simulation.sampling import sample_paths
    from teamkf.study import measurements as M
    from teamkf.study.scenario import load_packaged
    from teamkf.study.stream import stream_filter

    sc = load_packaged("platoon-4-steady")
    p = sample_paths(sc.system, check, 1, rng=3)
    ys = [y[0] for y in p.y]
    with tempfile.TemporaryDirectory() as d:
        f = Path(d) / "m.csv"
        M.write_measurements(f, ys)
        t0 = time.perf_counter()
        buf = io.BytesIO()
        stream_filter(sc, f, buf, fmt=".csv", progress=False)
        t_stream = time.perf_counter() - t0
    got = pd.read_csv(io.BytesIO(buf.getvalue()))["z0"].to_numpy()
    t0 = time.perf_counter()
    res = M.filter_log(sc, ys, with_innovations=False)
    t_online = time.perf_counter() - t0
    ref = M.estimates_frame(res.estimates, sc.n_agents)["z0"].to_numpy()
    return float(np.max(np.abs(got - ref))), t_stream / check, t_online / check


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--steps", type=int, default=1_000_000)
    ap.add_argument("--format", choices=["parquet", "csv"], default="parquet")
    ap.add_argument("--out-format", choices=["parquet", "csv"], default=None, help="format of the estimates (default: as --format)")
    ap.add_argument("--check", type=int, default=2000, help="steps of the baseline comparison with the online agents")
    ap.add_argument("--keep", metavar="DIR", help="write the files here (default: a temporary folder)")
    a = ap.parse_args()
    print(f"load: {os.getloadavg()[0]:.2f} (1 min), cores: {os.cpu_count()}")
    d = Path(a.keep) if a.keep else Path(tempfile.mkdtemp(prefix="bench_filter_"))
    d.mkdir(parents=True, exist_ok=True)
    log, xs = d / f"log.{a.format}", d / "truth.parquet"
    out = d / f"z.{a.out_format or a.format}"
    t0 = time.perf_counter()
    write_log(log, xs, a.steps, a.format)
    print(f"wrote {a.steps} steps ({4 * a.steps} rows, {log.stat().st_size / 2**20:.0f} MiB) in {time.perf_counter() - t0:.1f} s")
    src = str(Path(__file__).resolve().parents[1] / "src")
    env = {**os.environ, "PYTHONPATH": src + os.pathsep + os.environ.get("PYTHONPATH", "")}
    cmd = [
        sys.executable,
        "-m",
        "teamkf",
        "filter",
        "platoon-4-steady",
        "--measurements",
        str(log),
        "--truth",
        str(xs),
        "--out",
        str(out),
        "--no-progress",
    ]
    t0 = time.perf_counter()
    r = subprocess.run(cmd, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 2**20  # KiB -> GiB
    print(r.stdout.strip())
    if r.returncode:
        print(r.stderr, file=sys.stderr)
        raise SystemExit(r.returncode)
    print(f"teamkf filter: {wall:.1f} s wall, peak RSS {peak:.3f} GiB, output {out.stat().st_size / 2**20:.0f} MiB (targets: < 60 s, < 1 GiB)")
    diff, _, to = baseline(a.check)
    per = wall / a.steps
    print(
        f"baseline, same run: the online agents (Monte Carlo runtime path) take {to * 1e6:.0f} us/step on {a.check} steps; "
        f"streaming took {per * 1e6:.1f} us/step over the whole file, reading and writing included (ratio {to / per:.0f}x); "
        f"max |z difference| on the {a.check} steps {diff:.2e}"
    )
    if not a.keep:
        for f in (log, xs, out, out.with_name(f"{out.stem}-cost{out.suffix}")):
            f.unlink(missing_ok=True)
        d.rmdir()


if __name__ == "__main__":
    main()
