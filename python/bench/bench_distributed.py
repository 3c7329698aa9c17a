"""umbra.distributed against one process, on this machine, in one run (issue 21): an
exhaustive capture (32 x 32 laser points x 32 x 32 sensor points, 1 048 576 measurements)
of the default scene's letter with `tri3` and with `path`, rendered

- by one process (`umbra.render`, 2 threads),
- by Ray with 2 worker processes (`umbra.distributed.render`, 1 thread each), for several
  shard counts, streaming into a `.npy` memory map, and once into a y-tal `.hdf5`;
  with ``--nodes 2``, on two simulated Ray nodes (``ray.cluster_utils``: two raylets and
  object stores on this machine, so every shard crosses between object stores);

reporting wall time, peak resident memory of the driver and of each worker, the bits
compared with the one-process render, and the overhead per shard (the slope of wall time
against the shard count). From the measured per-measurement cost and per-shard overhead,
a paper estimate of a 64^4 exhaustive `path` render on 16 machines like this one.

    .venv/bin/python python/bench/bench_distributed.py [--scan 32] [--bins 128]
        [--spp 4,64] [--shards 8,32,128] [--nodes 1] [--out out/bench-distributed]

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


def _cluster(nodes: int):
    """Ray with 2 CPUs in all: one node (2 workers), or ``nodes`` nodes of 1 CPU each,
    simulated on this machine by ray.cluster_utils (each its own raylet and object
    store, so a shard rendered on another node crosses between object stores as it would
    between machines, over loopback)."""
    import ray
    if nodes == 1:
        ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
        return None
    from ray.cluster_utils import Cluster
    c = Cluster(initialize_head=True, head_node_args=dict(num_cpus=0))
    for _ in range(nodes):
        c.add_node(num_cpus=2 // nodes or 1)
    ray.init(address=c.address, log_to_driver=False)
    c.wait_for_nodes()
    return c


def _one_process(s, model, spp, rows):
    t0 = time.perf_counter()
    local = umbra.render(s, model=model, spp=spp, seed=1, threads=2)
    rows.append(dict(model=model, spp=spp, how="one process, 2 threads", shards=1, out="memory",
                     seconds=time.perf_counter() - t0, driver_peak_mb=peak_mb(), same_bits=True))
    print(rows[-1], flush=True)
    return local


def _ray_render(ray, s, model, spp, shards, out, local, how, rows):
    t0 = time.perf_counter()
    far = ud.render(s, model=model, spp=spp, seed=1, shards=shards, out=out, progress=False)
    t = time.perf_counter() - t0
    if out is not None and out.endswith(".hdf5"):
        same = None  # checked by python/tests/test_distributed.py (y-tal's reader)
    else:
        same = bool(np.array_equal(np.asarray(far).view(np.uint32), local.view(np.uint32)))
    peaks = ray.get([ray.remote(_worker_peak).remote(i) for i in range(8)])
    workers = {pid: mb for pid, mb in peaks}
    kind = "memory" if out is None else os.path.splitext(out)[1][1:]
    rows.append(dict(model=model, spp=spp, how=how, shards=shards, out=kind, seconds=t,
                     driver_peak_mb=peak_mb(), worker_peak_mb=sorted(workers.values()),
                     same_bits=same))
    print(rows[-1], flush=True)
    del far


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scan", type=int, default=32)
    ap.add_argument("--bins", type=int, default=128)
    ap.add_argument("--spp", default="4,64", help="path's spp values")
    ap.add_argument("--shards", default="8,32,128")
    ap.add_argument("--nodes", type=int, default=1,
                    help="1: one Ray node with 2 workers; 2: two simulated nodes of 1 CPU")
    ap.add_argument("--out", default="out/bench-distributed")
    a = ap.parse_args()
    os.makedirs(a.out, exist_ok=True)
    s = _exhaustive(a.scan, a.bins)
    n = int(np.prod(s.shape[:-1]))
    print(f"exhaustive {a.scan}^4 = {n} measurements x {a.bins} bins "
          f"({n * a.bins * 4 / 2**30:.2f} GiB float32), {a.nodes} Ray node(s)", flush=True)
    import ray
    cluster = _cluster(a.nodes)
    how = ("Ray, 2 workers x 1 thread" if a.nodes == 1
           else f"Ray, {a.nodes} nodes x 1 worker x 1 thread")
    shard_counts = [int(x) for x in a.shards.split(",")]
    rows = []
    cases = [("tri3", None)] + [("path", int(x)) for x in a.spp.split(",")]
    for model, spp in cases:
        local = _one_process(s, model, spp, rows)
        for shards in shard_counts:
            _ray_render(ray, s, model, spp, shards, os.path.join(a.out, f"{model}.npy"), local,
                        how, rows)
        # The y-tal capture, streamed by the driver as the shards arrive.
        _ray_render(ray, s, model, spp, shard_counts[len(shard_counts) // 2],
                    os.path.join(a.out, f"{model}.hdf5"), local, how, rows)
        del local
    # Overhead per shard: slope of wall time against the shard count, per case (.npy).
    summary = {}
    for model, spp in cases:
        key = model if spp is None else f"{model}@{spp}spp"
        mine = [r for r in rows if r["model"] == model and r["spp"] == spp]
        pts = [(r["shards"], r["seconds"]) for r in mine if r["shards"] > 1 and r["out"] == "npy"]
        k = np.polyfit([p[0] for p in pts], [p[1] for p in pts], 1)
        local = next(r["seconds"] for r in mine if r["shards"] == 1)
        h5 = next(r["seconds"] for r in mine if r["out"] == "hdf5")
        summary[key] = dict(per_shard_overhead_s=float(k[0]), intercept_s=float(k[1]),
                            one_process_s=local, best_ray_npy_s=min(p[1] for p in pts),
                            ray_hdf5_s=h5, per_measurement_us=1e6 * local * 2 / n)  # core-s
    # 64^4 exhaustive path on 16 machines like this one (2 cores each), per path spp.
    m64 = 64 ** 4
    out_gib = m64 * a.bins * 4 / 2**30
    for model, spp in cases[1:]:
        p = summary[f"{model}@{spp}spp"]
        core_s = p["per_measurement_us"] * 1e-6 * m64
        shards64 = 16 * 2 * 4
        est = core_s / (16 * 2) + shards64 * max(p["per_shard_overhead_s"], 0) / (16 * 2)
        summary[f"estimate_64^4_path@{spp}spp_16_machines"] = dict(
            measurements=m64, spp=spp, core_seconds=core_s, render_seconds=est,
            shards=shards64, output_gib=out_gib,
            transfer_s_at_1_gbit=out_gib * 2**30 * 8 / 1e9)
    tag = "" if a.nodes == 1 else f"_{a.nodes}nodes"
    with open(os.path.join(a.out, f"bench_distributed{tag}.json"), "w") as f:
        json.dump(dict(rows=rows, summary=summary, scan=a.scan, bins=a.bins, nodes=a.nodes),
                  f, indent=1)
    print("\n| model | spp | how | shards | output | wall time (s) | driver peak (MB) | "
          "worker peaks (MB) | same bits |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        wp = ", ".join(f"{x:.0f}" for x in r.get("worker_peak_mb", [])) or "-"
        same = {True: "yes", False: "NO", None: "(y-tal test)"}[r["same_bits"]]
        print(f"| {r['model']} | {r['spp'] or '-'} | {r['how']} | {r['shards']} | {r['out']} | "
              f"{r['seconds']:.2f} | {r['driver_peak_mb']:.0f} | {wp} | {same} |")
    print(json.dumps(summary, indent=1))
    ray.shutdown()
    if cluster is not None:
        cluster.shutdown()


if __name__ == "__main__":
    main()
