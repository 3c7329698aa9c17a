"""What the Python binding adds to a gradient: `umbra.grad` timed from Python against the
same gradient through the CLI (`umbra grad --adjoint`, whose own timer covers the
geometry build and the adjoint pass, not process start, scene parsing or file I/O), on
the default scene with `tri3`; then one `umbra.torch` Adam step split into its parts.

    UMBRA_BIN=target/release/umbra python python/bench/bench_binding.py [--repeat 5]

Prints a table; the ratio python/CLI is the binding's overhead (1.00 = none).
"""
from __future__ import annotations

import argparse
import os
import re
import statistics
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

import umbra

REPO = Path(__file__).resolve().parents[2]


def best(f, repeat):
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        f()
        times.append(time.perf_counter() - t0)
    return min(times), statistics.median(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--threads", type=int, default=None)
    args = ap.parse_args()
    exe = os.environ.get("UMBRA_BIN", str(REPO / "target" / "release" / "umbra"))
    scene_file = REPO / "scenes" / "default.toml"
    s = umbra.load_scene(str(scene_file))
    opts = dict(model="tri3", threads=args.threads)
    h = umbra.render(s, **opts)
    target = umbra.render(s.copy(), **opts) * np.float32(0.9)
    adj = (2 * (h - target)).astype(np.float32)
    rows = []

    # 1. The gradient alone, Python against the CLI's own timer.
    py_grad = best(lambda: umbra.grad(s, adj, **opts), args.repeat)

    def uncached():
        c = s.copy()
        c.set_vertices(c.vertices())  # drops the cached geometry, as a changed mesh does
        umbra.grad(c, adj, **opts)

    fresh = best(uncached, args.repeat)
    with tempfile.TemporaryDirectory() as tmp:
        np.save(Path(tmp) / "adj.npy", adj)
        cli = []
        for _ in range(args.repeat):
            cmd = [exe, "grad", str(scene_file), "--model", "tri3", "--adjoint",
                   str(Path(tmp) / "adj.npy"), "-o", str(Path(tmp) / "g.npz")]
            if args.threads:
                cmd += ["--threads", str(args.threads)]
            r = subprocess.run(cmd, capture_output=True, text=True, check=True)
            m = re.search(r"spp, ([0-9.]+) s\)", r.stderr)
            cli.append(float(m.group(1)))
    cli_t = (min(cli), statistics.median(cli))
    rows.append(("umbra.grad (scene geometry cached)", py_grad))
    rows.append(("umbra.grad (mesh just changed: geometry built)", fresh))
    rows.append(("CLI umbra grad --adjoint (its own timer)", cli_t))
    py_render = best(lambda: umbra.render(s, **opts), args.repeat)
    rows.append(("umbra.render", py_render))
    py_target = best(lambda: umbra.grad(s, target=target, **opts), args.repeat)
    rows.append(("umbra.grad(target=) (render + loss + adjoint)", py_target))

    # 2. One Adam step of umbra.torch, and its parts.
    try:
        import torch
        import umbra.torch as ut
    except ImportError:
        torch = None
    if torch is not None:
        m = ut.TransientModule(s, model="tri3", threads=args.threads)
        opt = torch.optim.Adam(m.parameters(), lr=1e-3)
        tt = torch.from_numpy(target)

        def step():
            opt.zero_grad()
            loss = ((m() - tt) ** 2).sum()
            loss.backward()
            opt.step()

        step()  # warm-up
        rows.append(("torch Adam step (render + backward)", best(step, args.repeat)))

    print(f"default scene, tri3, {s.shape} bins, {len(s.vertices())} vertices, "
          f"best / median of {args.repeat} (s)")
    print("| what | best | median |\n|---|---|---|")
    for name, (b, med) in rows:
        print(f"| {name} | {b:.3f} | {med:.3f} |")
    print(f"\nbinding overhead: umbra.grad / CLI gradient = {py_grad[0] / cli_t[0]:.2f} (best), "
          f"{py_grad[1] / cli_t[1]:.2f} (median)")


if __name__ == "__main__":
    main()
