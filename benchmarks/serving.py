"""Serving speed of the zoo's δ1 models, side by side with a plain torch forward pass of the same network.

Targets (issue 6): median latency of one prediction ≤ 50 µs on one core, batch throughput ≥ 1 million rows/s.

* one prediction: ``model.predict_row(x)`` (FFNN, ensemble) or ``stream.push(x)`` (GRU, hidden state carried):
  raw SI target quantities in, F21 with its interval out (groups, distortion features, range check, network,
  Eq. 22); against ``net(z)`` on one already-standardised float32 row under ``torch.inference_mode``;
* batch: ``model.predict_array(X)`` on 1 000 000 raw SI rows → F21, interval, extrapolation flags, on one core
  (``threads=1``) and on every usable core (the default); against ``net(Z)`` on the 1 000 000 standardised float32
  feature rows, one call with torch on one thread and one call with torch on every core (GRU: 1 000 sequences of
  1 000 steps both ways). Besides wall-clock rates, the all-core run's rows per second of process CPU time tells
  how much of a shortfall came from other jobs on the machine.

Latency runs on one thread (torch, OpenBLAS). Rows are the held-out check rows shipped with the checkpoints,
repeated. Run: ``python benchmarks/serving.py [--rows 1000000] [--out benchmarks/results/serving.md]``.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import datetime as dt  # noqa: E402
import math  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from collections.abc import Callable  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402
import torch  # noqa: E402

import zoo  # noqa: E402
from scaletwin_envs.host import host_line  # noqa: E402
from scaling.runs.provenance import code_version, versions  # noqa: E402
from zoo.build import ENTRIES  # noqa: E402
from zoo.product_line import NAME as PRODUCT_LINE  # noqa: E402
from zoo.scaling_kind import check_rows  # noqa: E402
from zoo.serving.kernels import CHUNK, EnsembleKernel, GRUKernel  # noqa: E402
from zoo.serving.parallel import usable_cores  # noqa: E402

LATENCY_TARGET_US = 50.0
THROUGHPUT_TARGET = 1_000_000


def median_latency_us(fn: Callable[[int], Any], calls: int) -> float:
    """Median wall time of ``fn(i)`` over ``calls`` calls (after 200 warm-up calls), µs."""
    for i in range(200):
        fn(i)
    times = []
    clock = time.perf_counter
    for i in range(calls):
        start = clock()
        fn(i)
        times.append(clock() - start)
    return 1e6 * statistics.median(times)


def best_rate(fn: Callable[[], Any], rows: int, repeats: int, cpu: bool = False) -> Any:
    """Rows per second of the fastest of ``repeats`` runs of ``fn`` (after one warm-up run); with ``cpu``, also
    rows per second of process CPU time (all threads) of that run."""
    fn()
    wall, cpu_s = min(_timed(fn) for _ in range(repeats))
    return (rows / wall, rows / cpu_s) if cpu else rows / wall


def _timed(fn: Callable[[], Any]) -> tuple[float, float]:
    """(wall, process CPU) seconds of one call."""
    start, start_cpu = time.perf_counter(), time.process_time()
    fn()
    return time.perf_counter() - start, time.process_time() - start_cpu


def inputs(model: zoo.ScalingModel, n_rows: int) -> tuple[np.ndarray, np.ndarray]:
    """(raw SI rows (n, v), their standardised float32 features (n, k) for the plain torch pass)."""
    check = check_rows(zoo.resolve(model.name)[0])
    base = check[[f"{d['name']} [{d['unit']}]" for d in model.card["inputs"]]].to_numpy(float)
    x = np.tile(base, (n_rows // len(base) + 1, 1))[:n_rows]
    g, _ = model._features_of(x, 0)
    kernel = model.kernel
    if isinstance(kernel, EnsembleKernel):
        z = (g - kernel.x_mean[0]) / kernel.x_std[0]
    else:
        z = (g - kernel.x_mean) / kernel.x_std
    return x, np.ascontiguousarray(z, dtype=np.float32)


def plain_nets(model: zoo.ScalingModel) -> list[torch.nn.Module]:
    kernel = model.kernel
    return list(kernel.nets) if isinstance(kernel, EnsembleKernel) else [kernel.net]


def bench_model(name: str, n_rows: int, calls: int, repeats: int) -> dict[str, Any]:
    model = zoo.load(name)
    x, z = inputs(model, n_rows)
    nets = plain_nets(model)
    recurrent = isinstance(model.kernel, GRUKernel)
    rows_list = [list(r) for r in x[:1000]]
    z1 = torch.from_numpy(z[:1].copy())
    if recurrent:
        stream = model.stream()
        ours_one = median_latency_us(lambda i: stream.push(rows_list[i % 1000]), calls)
        h = [None]

        def torch_step(_: int) -> None:
            out, h[0] = nets[0].gru(z1[None], h[0])
            nets[0].head(out)
    else:
        ours_one = median_latency_us(lambda i: model.predict_row(rows_list[i % 1000]), calls)

        def torch_step(_: int) -> None:
            for net in nets:
                net(z1)
    with torch.inference_mode():
        torch_one = median_latency_us(torch_step, calls)
    length = 1000
    seqs = np.arange(n_rows).reshape(-1, length) if recurrent else None
    zt = torch.from_numpy(z.reshape(-1, length, z.shape[1]) if recurrent else z)
    cores = usable_cores()

    def torch_batch() -> None:
        with torch.inference_mode():
            for net in nets:
                net(zt)

    ours_1 = best_rate(lambda: model.predict_array(x, sequences=seqs, threads=1, risk=False), n_rows, repeats)
    torch_1 = best_rate(torch_batch, n_rows, repeats)
    ours_all, ours_cpu = best_rate(lambda: model.predict_array(x, sequences=seqs, risk=False), n_rows, repeats,
                                   cpu=True)
    n_risk = min(n_rows, 100_000)
    risk_rate = (best_rate(lambda: model.predict_array(x[:n_risk]), n_risk, 1) if model.risk is not None
                 else float("nan"))
    torch.set_num_threads(cores)
    torch_all = best_rate(torch_batch, n_rows, repeats)
    torch.set_num_threads(1)
    arch = model.card["model"]
    return {"name": name, "class": arch["class"], "ours_us": ours_one, "torch_us": torch_one, "ours_1": ours_1,
            "torch_1": torch_1, "ours_all": ours_all, "torch_all": torch_all, "ours_cpu": ours_cpu, "cores": cores,
            "risk_rate": risk_rate,
            "batch_note": f"{n_rows // length} sequences × {length} steps" if recurrent else f"{n_rows} rows"}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=1_000_000)
    ap.add_argument("--calls", type=int, default=20_000)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--models", nargs="+", default=[*(e.name for e in ENTRIES), PRODUCT_LINE])
    ap.add_argument("--out", default="benchmarks/results/serving.md")
    args = ap.parse_args()
    torch.set_num_threads(1)
    warnings.simplefilter("ignore", zoo.ExtrapolationWarning)  # the repeated check rows include some
    load_start = os.getloadavg()[0]
    results = []
    for name in args.models:
        res = bench_model(name, args.rows, args.calls, args.repeats)
        results.append(res)
        print(f"{name}: one row {res['ours_us']:.1f} µs (torch {res['torch_us']:.1f} µs), batch on one core "
              f"{res['ours_1'] / 1e6:.2f} M rows/s (torch {res['torch_1'] / 1e6:.2f}), on {res['cores']} cores "
              f"{res['ours_all'] / 1e6:.2f} M rows/s (torch {res['torch_all'] / 1e6:.2f})", flush=True)
    text = report(results, args.rows, load_start)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text)
    print(text)


def report(results: list[dict[str, Any]], rows: int, load_start: float) -> str:
    """The Markdown of ``benchmarks/results/serving.md``."""
    cores = results[0]["cores"]
    lines = [f"# serving ({dt.datetime.now(dt.UTC):%Y-%m-%d %H:%M} UTC, {host_line()})", "",
             f"Code `{code_version()}`; {versions()}.", "",
             "One prediction (one thread) = raw SI target quantities → F21 with its interval and extrapolation check "
             "(`predict_row`; GRU: `stream.push`, state carried). Plain torch = the same network's forward pass on "
             "one already-standardised float32 row (`torch.inference_mode`). Batch = `predict_array` on "
             f"{rows} raw SI rows → F21, interval and flags, in {CHUNK}-row chunks, on one core (`threads=1`) and on "
             f"all {cores} usable cores (the default; threads over chunks, see `zoo.serving.parallel`), vs one plain "
             "`net(Z)` call on their standardised float32 features with torch on one thread and on all cores. "
             "Ratio = ours / plain torch (latency: lower is better; throughput: higher is better). "
             "CPU-time rate = rows per second of process CPU time in the all-core run (what the cores did, whatever "
             "else the machine was running). Batches skip the per-row error score (`risk=False`); the last column "
             "times it on 100 000 rows where a checkpoint carries one (a nearest-neighbour query per row).", "",
             "| model | one prediction, median [µs] | plain torch [µs] | ratio | ≤ 50 µs | batch, 1 core [M rows/s] | "
             "plain torch, 1 core | ratio | batch, all cores [M rows/s] | plain torch, all cores | ratio | "
             "CPU-time rate [M rows/CPU-s] | ≥ 1 M rows/s | batch | with the error score, all cores [k rows/s] |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        best = max(r["ours_1"], r["ours_all"])
        risk = "–" if math.isnan(r["risk_rate"]) else f"{r['risk_rate'] / 1e3:.0f}"
        lines.append(f"| {r['name']} ({r['class']}) | {r['ours_us']:.1f} | {r['torch_us']:.1f} | "
                     f"{r['ours_us'] / r['torch_us']:.2f} | {'yes' if r['ours_us'] <= LATENCY_TARGET_US else 'no'} | "
                     f"{r['ours_1'] / 1e6:.2f} | {r['torch_1'] / 1e6:.2f} | {r['ours_1'] / r['torch_1']:.2f} | "
                     f"{r['ours_all'] / 1e6:.2f} | {r['torch_all'] / 1e6:.2f} | {r['ours_all'] / r['torch_all']:.2f} | "
                     f"{r['ours_cpu'] / 1e6:.2f} | {'yes' if best >= THROUGHPUT_TARGET else 'no'} | "
                     f"{r['batch_note']} | {risk} |")
    lines += ["", f"Machine load average (1 min): {load_start:.1f} at the start, {os.getloadavg()[0]:.1f} at the end "
              f"({cores} cores; above {cores} other jobs were competing for them).", ""]
    return "\n".join(lines)


if __name__ == "__main__":
    main()
