"""Peak memory of `umbra render` where it used to grow: Monte Carlo against spp (one
measurement, 4096 bins, `mc3`) and `tri3` on a 1 x 1 scan with 1e8 bins (a 400 MB
output). Each render runs in its own process; the peak is that child's maximum resident
set (`getrusage`). With `--baseline OTHER_UMBRA` the same renders run with another
build in the same session, and the outputs are compared byte for byte.

    python python/bench/bench_memory.py --umbra target/release/umbra [--baseline old/umbra]

Needs only the standard library (Linux: `ru_maxrss` is in KiB).
"""
from __future__ import annotations

import argparse
import filecmp
import os
import subprocess
import tempfile
import time
from pathlib import Path

SQUARE = "v -0.1 -0.1 0\nv 0.1 -0.1 0\nv 0.1 0.1 0\nv -0.1 0.1 0\nf 1 2 3 4\n"
SCENE = """capture_type = "confocal"
[wall]
size = [2.0, 2.0]
[laser]
origin = [0.0, -2.0, 1.5]
[scan]
resolution = [1, 1]
[film]
temporal_bins = {bins}
bin_width_opl = 0.01
[[objects]]
file = "sq.obj"
transform = {{ translate = [0.0, 0.0, 1.0] }}
[render]
model = "{model}"
"""

CASES = [
    ("mc3, 4096 bins, spp 4e6", "mc3", 4096, 4_000_000),
    ("mc3, 4096 bins, spp 1.6e7", "mc3", 4096, 16_000_000),
    ("mc3, 4096 bins, spp 6.4e7", "mc3", 4096, 64_000_000),
    ("tri3, 1e8 bins (400 MB output)", "tri3", 100_000_000, 1),
]


def peak(binary: str, scene: Path, spp: int, out: Path) -> tuple[float, float]:
    """(peak RSS in MiB, seconds) of one render in a fresh child process."""
    cmd = [binary, "render", str(scene), "--spp", str(spp), "-o", str(out), "-q", "--no-preview"]
    t0 = time.perf_counter()
    child = subprocess.Popen(cmd, stderr=subprocess.DEVNULL)
    _, status, usage = os.wait4(child.pid, 0)
    if status != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({status})")
    return usage.ru_maxrss / 1024.0, time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--umbra", required=True)
    ap.add_argument("--baseline")
    args = ap.parse_args()
    builds = [("this build", args.umbra)] + ([("baseline", args.baseline)] if args.baseline else [])
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        (d / "sq.obj").write_text(SQUARE)
        print("| case | " + " | ".join(f"{n}: peak MiB (s)" for n, _ in builds) + " | same output |")
        print("|---|" + "---|" * len(builds) + "---|")
        for label, model, bins, spp in CASES:
            scene = d / f"{model}_{bins}.toml"
            scene.write_text(SCENE.format(bins=bins, model=model))
            cells, outs = [], []
            for name, binary in builds:
                out = d / f"{name.replace(' ', '_')}.npy"
                mib, secs = peak(binary, scene, spp, out)
                cells.append(f"{mib:.0f} ({secs:.1f})")
                outs.append(out)
            same = "yes" if len(outs) == 1 or filecmp.cmp(outs[0], outs[1], shallow=False) else "NO"
            print(f"| {label} | " + " | ".join(cells) + f" | {same if len(outs) > 1 else '-'} |")
            for o in outs:
                o.unlink()


if __name__ == "__main__":
    main()
