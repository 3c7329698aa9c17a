"""umbra.distributed against one process, on this machine, in one run (issue 21): an
exhaustive capture (32 x 32 laser points x 32 x 32 sensor points, 1 048 576 measurements)
of the default scene's letter with `tri3` and with `path`, rendered

- by one process (`umbra.render`, 2 threads),
- by Ray with 2 worker processes (`umbra.distributed.render`, 1 thread each), for several
  shard counts, streaming into a `.npy` memory map;

reporting wall time, peak resident memory of the driver and of each worker, the bits
compared with the one-process render, and the overhead per shard (the slope of wall time
against the shard count). From the measured per-measurement cost and per-shard overhead,
a paper estimate of a 64^4 exhaustive `path` render on 16 machines like this one.

    .venv/bin/python python/bench/bench_distributed.py [--scan 32] [--bins 128]
        [--spp 4] [--shards 8,32,128] [--out out/bench-distributed]

Writes OUT/bench_distributed.json and prints a Markdown table (docs/BENCHMARKS.md).
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import tempfile
import time

import numpy as np

import umbra
import umbra.distributed as ud


def _exhaustive(scan: int, bins: int) -> umbra.Scene:
    here = os.path.dirname(os.path.abspath(__file__))
    root = os.path.dirname(os.path.dirname(here))
    text = open(os.path.join(root, "scenes", "default.toml"), encoding="utf-8").read()
    lines = []
    for line in text.splitlines():
        if line.startswith("capture_type"):
            line = 'capture_type = "exhaustive"'
        elif line.startswith("resolution"):
            line = f"resolution = [{scan}, {scan}]"
        elif line.startswith("temporal_bins"):
            line = f"temporal_bins = {bins}"
        lines.append(line)
    # Into a temporary folder (not the repository), with the mesh found from there.
    text = "\n".join(lines).replace('"meshes/', f'"{os.path.join(root, "scenes", "meshes")}/')
    with tempfile.TemporaryDirectory(prefix="umbra-bench-") as d:
        path = os.path.join(d, "exhaustive.toml")
        with open(path, "w", encoding="utf-8") as f:
            f.write(text + "\n")
        return umbra.load_scene(path)


def peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _worker_peak(_):
    import resource as r
    return os.getpid(), r.getrusage(r.RUSAGE_SELF).ru_maxrss / 1024.0


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scan", type=int, default=32)
    ap.add_argument("--bins", type=int, default=128)
    ap.add_argument("--spp", type=int, default=4)
    ap.add_argument("--shards", default="8,32,128")
    ap.add_argument("--out", default="out/bench-distributed")
    a = ap.parse_args()
    os.makedirs(a.out, exist_ok=True)
    s = _exhaustive(a.scan, a.bins)
    n = int(np.prod(s.shape[:-1]))
    print(f"exhaustive {a.scan}^4 = {n} measurements x {a.bins} bins "
          f"({n * a.bins * 4 / 2**30:.2f} GiB float32)", flush=True)
    import ray
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    rows = []
    for model, spp in [("tri3", None), ("path", a.spp)]:
        t0 = time.perf_counter()
        local = umbra.render(s, model=model, spp=spp, seed=1, threads=2)
        t_local = time.perf_counter() - t0
        rows.append(dict(model=model, how="one process, 2 threads", shards=1, seconds=t_local,
                         driver_peak_mb=peak_mb(), same_bits=True))
        print(rows[-1], flush=True)
        for shards in [int(x) for x in a.shards.split(",")]:
            path = os.path.join(a.out, f"{model}.npy")
            t0 = time.perf_counter()
            far = ud.render(s, model=model, spp=spp, seed=1, shards=shards, out=path,
                            progress=False)
            t = time.perf_counter() - t0
            same = bool(np.array_equal(np.asarray(far).view(np.uint32), local.view(np.uint32)))
            peaks = ray.get([ray.remote(_worker_peak).remote(i) for i in range(8)])
            workers = {pid: mb for pid, mb in peaks}
            rows.append(dict(model=model, how="Ray, 2 workers x 1 thread", shards=shards,
                             seconds=t, driver_peak_mb=peak_mb(),
                             worker_peak_mb=sorted(workers.values()), same_bits=same))
            print(rows[-1], flush=True)
            del far
        del local
    # Overhead per shard: slope of wall time against the shard count, per model.
    summary = {}
    for model in ("tri3", "path"):
        pts = [(r["shards"], r["seconds"]) for r in rows if r["model"] == model and r["shards"] > 1]
        k = np.polyfit([p[0] for p in pts], [p[1] for p in pts], 1)
        local = next(r["seconds"] for r in rows if r["model"] == model and r["shards"] == 1)
        best = min(p[1] for p in pts)
        summary[model] = dict(per_shard_overhead_s=float(k[0]), intercept_s=float(k[1]),
                              one_process_s=local, best_ray_s=best,
                              per_measurement_us=1e6 * local * 2 / n)  # core-seconds
    # 64^4 exhaustive path on 16 machines like this one (2 cores each).
    m64 = 64 ** 4
    p = summary["path"]
    core_s = p["per_measurement_us"] * 1e-6 * m64
    shards64 = 16 * 2 * 4
    est = core_s / (16 * 2) + shards64 * max(p["per_shard_overhead_s"], 0) / (16 * 2)
    out_gib = m64 * a.bins * 4 / 2**30
    summary["estimate_64^4_path_16_machines"] = dict(
        measurements=m64, spp=a.spp, core_seconds=core_s, seconds=est, shards=shards64,
        output_gib=out_gib, transfer_s_at_1_gbit=out_gib * 2**30 * 8 / 1e9)
    with open(os.path.join(a.out, "bench_distributed.json"), "w") as f:
        json.dump(dict(rows=rows, summary=summary, scan=a.scan, bins=a.bins, spp=a.spp), f, indent=1)
    print("\n| model | how | shards | wall time (s) | driver peak (MB) | worker peaks (MB) | same bits |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        wp = ", ".join(f"{x:.0f}" for x in r.get("worker_peak_mb", [])) or "-"
        print(f"| {r['model']} | {r['how']} | {r['shards']} | {r['seconds']:.2f} | "
              f"{r['driver_peak_mb']:.0f} | {wp} | {r['same_bits']} |")
    print(json.dumps(summary, indent=1))


if __name__ == "__main__":
    main()
