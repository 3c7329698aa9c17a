"""tri3 gradient against tri3 render, through the Python package (issue 19's "before and
after" numbers): the built-in default scene (32 x 32 confocal, 512 bins, 72 triangles),
``umbra.render`` against ``umbra.grad`` with a fixed random adjoint (boundary terms on, the
default, and off), and one Adam step of a torch loop over ``TransientModule`` (forward,
L2 loss, backward, step). Medians of interleaved repetitions; ratios are what to compare
across runs on a shared machine.

    python python/bench/bench_tri3_grad.py [--reps 7] [--scene scenes/default.toml]
"""
import argparse
import statistics
import time

import numpy as np
import umbra


def timed(f):
    t = time.perf_counter()
    f()
    return time.perf_counter() - t


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reps", type=int, default=7)
    ap.add_argument("--scene", default="scenes/default.toml")
    args = ap.parse_args()
    scene = umbra.load_scene(args.scene)
    h = umbra.render(scene, model="tri3")
    adj = np.random.default_rng(1).standard_normal(h.shape).astype(np.float32)
    runs = {"render": lambda: umbra.render(scene, model="tri3"),
            "grad": lambda: umbra.grad(scene, adj, model="tri3"),
            "grad, no boundary terms": lambda: umbra.grad(scene, adj, model="tri3",
                                                          boundary_terms=False)}
    try:
        import torch
        from umbra.torch import TransientModule
        module = TransientModule(scene, model="tri3")
        target = torch.from_numpy(h * 1.1)
        opt = torch.optim.Adam(module.parameters(), lr=1e-3)

        def step():
            opt.zero_grad()
            loss = ((module() - target) ** 2).sum()
            loss.backward()
            opt.step()
        runs["torch Adam step"] = step
    except ImportError:
        pass
    times = {k: [] for k in runs}
    for _ in range(args.reps):
        for k, f in runs.items():
            times[k].append(timed(f))
    med = {k: statistics.median(v) for k, v in times.items()}
    print(f"| {args.scene}, tri3 | median s | / render |")
    print("|---|---|---|")
    for k, v in med.items():
        print(f"| {k} | {v:.4f} | {v / med['render']:.1f} |")


if __name__ == "__main__":
    main()
