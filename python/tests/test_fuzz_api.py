"""Fuzzes the Python entry points (``umbra.render``, ``umbra.grad``, ``umbra.fit``): random
keyword values, many absurd (0, -1, NaN, inf, 1e30, wrong types, arrays of the wrong shape
or layout), on a small scene. Each call must return or raise a Python exception; a crash
of the interpreter (abort, segfault, a Rust panic crossing the boundary) fails the test.

The calls run in one child interpreter that prints each case before running it, so a
crash names the case. ``UMBRA_FUZZ_PY_CASES`` sets the number of cases (default 40),
``UMBRA_FUZZ_PY_SEED`` the seed (fixed by default: CI is reproducible)."""
from __future__ import annotations

import os
import subprocess
import sys
import textwrap

CHILD = textwrap.dedent(
    """
    import math, random, sys, warnings
    from pathlib import Path
    import numpy as np
    import umbra
    sys.path.insert(0, {here!r})
    from scenes_two import two_object_scene

    warnings.simplefilter("ignore")
    rng = random.Random({seed})
    scene = two_object_scene(Path({tmp!r}), scan=4)
    good = umbra.render(scene, model="tri3")
    wild = [0, -1, 1, 2, 7, 1e30, -1e30, math.nan, math.inf, 1e-30, 3, "x", None, 2**70, True]

    sane = {{
        "spp": [1, 4, 16], "model": ["tri3", "mc3", "path", "auto"], "seed": [0, 1, 5],
        "threads": [1, 2], "max_depth": [3, 4, 5], "subdivision": [0.1, 0.3],
        "visibility": ["none", "centroid"], "iters": [1, 2, 3], "jitter": [0.0, 0.004],
        "ignore_before": [0.0, 0.5], "time_offset": [0.0, 0.01], "target_spp": [16],
        "bin": [(1, 1), (2, 1)], "background": ["none", "constant", "per-bin"],
    }}

    def value(name):
        # Half sane values, so calls reach the renderer and the fit, half wild ones.
        return rng.choice(sane[name] if rng.random() < 0.5 else wild)

    def array():
        return rng.choice([
            good, good.T, np.asfortranarray(good), good[::-1], good[..., :3], np.zeros(3),
            np.full_like(good, np.nan), good.astype(np.float64) * 1e30, good.astype(np.int8),
        ])

    render_keys = ["spp", "model", "seed", "threads", "max_depth", "subdivision", "visibility"]
    fit_keys = ["iters", "jitter", "ignore_before", "time_offset", "spp", "target_spp", "bin", "background"]
    for case in range({cases}):
        entry = rng.choice(["render", "grad", "fit"])
        keys = render_keys if entry != "fit" else fit_keys
        kw = {{k: value(k) for k in rng.sample(keys, rng.randint(1, 3))}}
        if entry == "fit":
            kw.setdefault("iters", 1)
        print(case, entry, kw, flush=True)
        try:
            s = scene.copy()
            if entry == "render":
                umbra.render(s, **kw)
            elif entry == "grad":
                umbra.grad(s, target=array(), **kw)
            else:
                umbra.fit(s, array(), init="scene", output=Path({tmp!r}) / f"fit{{case}}", **kw)
        except (umbra.UmbraError, TypeError, ValueError, OverflowError, IndexError) as e:
            print("  refused:", type(e).__name__, str(e)[:200], flush=True)
    print("done", flush=True)
    """
)


def test_python_entry_points_never_crash(tmp_path):
    cases = int(os.environ.get("UMBRA_FUZZ_PY_CASES", "40"))
    seed = int(os.environ.get("UMBRA_FUZZ_PY_SEED", "20261207"))
    code = CHILD.format(here=os.path.dirname(__file__), tmp=str(tmp_path), seed=seed, cases=cases)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=1200)
    last = [l for l in r.stdout.splitlines() if l and not l.startswith("  ")][-1:] or ["(none)"]
    assert r.returncode == 0 and r.stdout.rstrip().endswith("done"), (
        f"exit {r.returncode} at case {last[0]}\n{r.stderr[-3000:]}")
