"""mitransient 1.3.1 on the scenes of `umbra bench accuracy`: error against wall-clock time,
next to every Umbra method, in one run on one machine.

Run from the repository root (needs target/release/umbra and the .venv of the
cross-validation suite, DESIGN.md section 7):

    .venv/bin/python python/bench/bench_accuracy_mitransient.py

Options: --scenes letter,sphere,bunny,corner  --budget S (stop a mitransient curve after a
render longer than S seconds; default 30)  --umbra-budget S (the same for Umbra's curves;
default 4, as `umbra bench accuracy`)  --threads 2  --reference-spp 262144.

Steps:
1. `umbra bench accuracy --export-mitsuba docs/accuracy_cache/mitsuba`: the converged
   references (path tracer, all techniques, two halves; cached) and each scene written as
   Mitsuba XML by Umbra's exporter (scene::mitsuba_xml::write, round trip tested in
   tests/mitsuba_export.rs): three-bounce (max_depth 3, filter_bounces 2) and multi-bounce
   (the reference's 8 bounces) with laser + hidden-geometry sampling, mitransient's NLOS
   techniques, and multi-bounce with laser + BSDF sampling (hidden-geometry sampling off).
2. The scenes' Gaussian kernel (sigma 8 mm of OPL): mitransient 1.3.1 reads
   temporal_filter = gaussian but bins with a box, so it renders box bins 8x finer (1 mm)
   over the window widened by 4 sigma, and this script integrates each fine bin against the
   Gaussian over each coarse bin, taking the OPL uniform within a fine bin. The bias of
   that step is measured with Umbra's deterministic tri3 (same sub-triangles: subdivision
   threshold scaled with the bin width): fine box then converted, against the Gaussian
   render directly.
3. mitransient ladders: spp 4, 8, 16, ... (one seed per rung, the seed changing with spp),
   until a render takes longer than --budget. Time = wall clock of mi.render + np.array
   minus that render's JIT compile time (Dr.Jit's kernel history; a new spp compiles a new
   kernel). Scene loading is excluded, as Umbra's curves exclude the BVH build.
   Error = relative L2 against the reference, the reference's own error removed in
   quadrature (as Umbra's).
4. `umbra bench accuracy --extra-curves docs/accuracy_mitransient.csv`: Umbra's curves in
   the same run, the chart docs/accuracy.png with mitransient's curves in it, and the
   table; then this script's ratios: time to 5 % and 1 % of mitransient's best curve
   against Umbra's best and against tri3, and the smallest lead of Umbra's best curve over
   mitransient's best across every error mitransient reaches.
"""
from __future__ import annotations

import argparse
import datetime
import math
import os
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "python" / "validation"))
import mtutil  # noqa: E402

UMBRA = ROOT / "target" / "release" / "umbra"
DOCS = ROOT / "docs"
EXPORT = DOCS / "accuracy_cache" / "mitsuba"
MT_CSV = DOCS / "accuracy_mitransient.csv"
METHODS = {
    "3b": "mitransient three-bounce (laser + HGS)",
    "mb": "mitransient multi-bounce (laser + HGS)",
    "mb_bsdf": "mitransient multi-bounce (laser + BSDF)",
}
XML_KEY = {"3b": "xml_three_bounce", "mb": "xml_multi_bounce", "mb_bsdf": "xml_multi_bounce_bsdf"}


# ------------------------------------------------------------------ the Gaussian kernel

def _G(x: np.ndarray, sigma: float) -> np.ndarray:
    """Antiderivative of Phi(x / sigma): x Phi(x/sigma) + sigma phi(x/sigma)."""
    from math import erf, sqrt, pi
    z = x / sigma
    Phi = 0.5 * (1.0 + np.vectorize(erf)(z / sqrt(2.0)))
    phi = np.exp(-0.5 * z * z) / sqrt(2.0 * pi)
    return x * Phi + sigma * phi


def gaussian_rebin(m: dict) -> np.ndarray:
    """Matrix (fine_bins, bins): a path of OPL uniform in fine bin j adds W[j, b] to coarse
    bin b under the Gaussian kernel integrated over the bin (DESIGN section 4):
    W = (1/d) int_{fine j} int_{bin b} g(t - tau) dt dtau."""
    d, sigma = m["fine_bin_width_opl"], m["sigma_opl"]
    lo_j = m["fine_start_opl"] + d * np.arange(m["fine_bins"])[:, None]
    hi_j = lo_j + d
    lo_b = m["start_opl"] + m["bin_width_opl"] * np.arange(m["bins"])[None, :]
    hi_b = lo_b + m["bin_width_opl"]
    W = (_G(hi_b - lo_j, sigma) - _G(hi_b - hi_j, sigma)
         - _G(lo_b - lo_j, sigma) + _G(lo_b - hi_j, sigma)) / d
    return W


def to_coarse(H_fine: np.ndarray, W: np.ndarray) -> np.ndarray:
    """(..., fine_bins) -> flat (measurements * bins) in Umbra's order (sy, sx, T)."""
    return (H_fine.reshape(-1, W.shape[0]).astype(np.float64) @ W).reshape(-1)


def rel_l2(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


# ------------------------------------------------------------------ steps

def run(cmd: list[str]) -> str:
    print("$", " ".join(str(c) for c in cmd), flush=True)
    r = subprocess.run([str(c) for c in cmd], cwd=ROOT, capture_output=True, text=True)
    if r.returncode != 0:
        sys.exit(f"failed ({r.returncode}): {r.stderr[-2000:]}")
    return r.stdout


def umbra_tri3(xml: Path, out: Path, subdivision: float, threads: int) -> np.ndarray:
    run([UMBRA, "render", xml, "--model", "tri3", "--visibility", "subtriangle",
         "--subdivision", subdivision, "--threads", threads, "-o", out, "--no-preview", "-q"])
    return np.load(out)


def conversion_bias(name: str, m: dict, W: np.ndarray, threads: int) -> float:
    """tri3 at fine box bins, converted, against tri3 with the Gaussian at coarse bins
    (same sub-triangles). Returns the relative L2 of the difference."""
    xml = EXPORT / m["xml_three_bounce"]
    text = xml.read_text()
    coarse = (text.replace('<string name="temporal_filter" value="box"/>',
                           '<string name="temporal_filter" value="gaussian"/>'
                           f'<float name="gaussian_stddev" value="{m["sigma_opl"]}"/>')
              .replace(f'name="temporal_bins" value="{m["fine_bins"]}"',
                       f'name="temporal_bins" value="{m["bins"]}"')
              .replace(f'name="bin_width_opl" value="{m["fine_bin_width_opl"]}"',
                       f'name="bin_width_opl" value="{m["bin_width_opl"]}"')
              .replace(f'name="start_opl" value="{m["fine_start_opl"]}"',
                       f'name="start_opl" value="{m["start_opl"]}"'))
    assert coarse.count("gaussian_stddev") == 1 and f'value="{m["bins"]}"' in coarse
    cxml = EXPORT / f"{name}_3b_gaussian.xml"
    cxml.write_text(coarse)
    s = 0.15
    fine = umbra_tri3(xml, EXPORT / f"{name}_tri3_fine.npy", s * m["fine_factor"], threads)
    direct = umbra_tri3(cxml, EXPORT / f"{name}_tri3_coarse.npy", s, threads)
    return rel_l2(to_coarse(fine, W), direct.reshape(-1).astype(np.float64))


class Mitransient:
    def __init__(self, threads: int):
        self.mi, _ = mtutil.setup(threads)

    def render(self, scene, spp: int, seed: int):
        import drjit as dr
        dr.set_flag(dr.JitFlag.KernelHistory, True)
        dr.kernel_history()
        t0 = time.perf_counter()
        _, transient = self.mi.render(scene, spp=spp, seed=seed)
        H = mtutil.to_numpy(transient)
        dt = time.perf_counter() - t0
        hist = [h for h in dr.kernel_history() if "cache_hit" in h]
        comp = sum(h.get("codegen_time", 0.0) + h.get("backend_time", 0.0) for h in hist) / 1e3
        return H, dt - comp


def curves(mt: Mitransient, name: str, m: dict, ref: np.ndarray, ref_err: float,
           W: np.ndarray, budget: float, notes: list[str]) -> list[tuple]:
    """The ladders; appends to `notes` each curve's last render's total against the
    reference's (a bias shows there, noise hardly)."""
    rows = []
    for kind in METHODS:
        xml = EXPORT / m[XML_KEY[kind]]
        scene = mtutil.load_xml(xml)
        mt.render(scene, 1, 0)  # warm-up: first-launch costs out of the curve
        spp = 4
        while True:
            H, secs = mt.render(scene, spp, seed=1000 + spp)
            raw = rel_l2(to_coarse(H, W), ref)
            err = math.sqrt(max(0.0, raw * raw - ref_err * ref_err))
            rows.append((name, METHODS[kind], spp, secs, err, raw))
            print(f"  {name} {kind} {spp:7d} spp  {secs:8.3f} s  {100 * err:8.3f} %", flush=True)
            if secs > budget or spp >= 1 << 20:
                break
            spp *= 2
        total = to_coarse(H, W).sum() / ref.sum()
        notes.append(f"{name}: {METHODS[kind]} at {spp} spp: total {total:.4f} x the "
                     f"reference's, relative L2 {100 * err:.2f} %")
        print(notes[-1], flush=True)
    return rows


def time_to(pts: list[tuple[float, float]], target: float) -> float | None:
    """First time (log-log interpolation) at which the error falls to target; as
    umbra::bench::accuracy::time_to."""
    pts = sorted(p for p in pts if p[1] > 0)
    if pts and pts[0][1] <= target:
        return pts[0][0]
    for (t0, e0), (t1, e1) in zip(pts, pts[1:]):
        if e0 > target >= e1:
            f = (math.log(target) - math.log(e0)) / (math.log(e1) - math.log(e0))
            return math.exp(math.log(t0) + f * (math.log(t1) - math.log(t0)))
    return None


def envelope_time(curves_: dict, methods: list[str], target: float):
    """The fastest of `methods` to `target`: (seconds, method) or (None, None)."""
    best = (None, None)
    for meth in methods:
        t = time_to(curves_.get(meth, []), target)
        if t is not None and (best[0] is None or t < best[0]):
            best = (t, meth)
    return best


def read_csv(path: Path) -> dict:
    out: dict = {}
    for line in path.read_text().splitlines()[1:]:
        scene, method, _setting, secs, err, _raw = line.split(",")
        out.setdefault(scene, {}).setdefault(method, []).append((float(secs), float(err)))
    return out


def ratios(scenes: list[str]) -> str:
    umbra = read_csv(DOCS / "accuracy.csv")
    mtr = read_csv(MT_CSV)
    fmt = lambda t: "not reached" if t is None else f"{t:.3g} s"  # noqa: E731
    lines = ["| scene | target | mitransient (best) | Umbra (best) | ratio | tri3 | ratio |",
             "|---|---|---|---|---|---|---|"]
    lead = ["", "| scene | smallest lead of Umbra's best over mitransient's best "
            "(over mitransient's points) | at error |", "|---|---|---|"]
    for s in scenes:
        U, M = umbra.get(s, {}), mtr.get(s, {})
        for target in (0.05, 0.01):
            tm, mm = envelope_time(M, list(M), target)
            tu, mu = envelope_time(U, list(U), target)
            tt, _ = envelope_time(U, [k for k in U if k.startswith("tri3")], target)
            r = lambda a: "" if a is None or tm is None else f"{tm / a:.0f}x"  # noqa: E731
            lines.append(f"| {s} | {100 * target:g} % | {fmt(tm)} ({mm or '-'}) | {fmt(tu)} "
                         f"({mu or '-'}) | {r(tu)} | {fmt(tt)} | {r(tt)} |")
        worst = None
        for meth, pts in M.items():
            for secs, err in pts:
                tu, _ = envelope_time(U, list(U), err)
                if err > 0 and tu is not None:
                    tm, _ = envelope_time(M, list(M), err)
                    if tm is not None and (worst is None or tm / tu < worst[0]):
                        worst = (tm / tu, err)
        if worst:
            lead.append(f"| {s} | {worst[0]:.1f}x | {100 * worst[1]:.2f} % |")
    return "\n".join(lines + lead)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", default="letter,sphere,bunny,corner")
    ap.add_argument("--budget", type=float, default=30.0)
    ap.add_argument("--umbra-budget", type=float, default=4.0)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--reference-spp", type=int, default=262144)
    a = ap.parse_args()
    scenes = a.scenes.split(",")
    started = datetime.datetime.now()
    print(run([UMBRA, "bench", "accuracy", "--export-mitsuba", EXPORT, "--scenes", a.scenes,
               "--reference-spp", a.reference_spp, "--threads", a.threads]))
    mt = Mitransient(a.threads)
    rows, notes = [], []
    for name in scenes:
        m = tomllib.loads((EXPORT / f"{name}.toml").read_text())
        W = gaussian_rebin(m)
        halves = np.load(m["reference"]).astype(np.float64)
        ref = halves.mean(0)
        bias = conversion_bias(name, m, W, a.threads)
        notes.append(f"{name}: reference error {100 * m['reference_error']:.3f} %, fine-box "
                     f"to Gaussian conversion bias {100 * bias:.4f} % (tri3)")
        print(notes[-1], flush=True)
        rows += curves(mt, name, m, ref, m["reference_error"], W, a.budget, notes)
    with open(MT_CSV, "w") as f:
        f.write("scene,method,setting,seconds,error,raw_error\n")
        for r in rows:
            f.write(f"{r[0]},{r[1]},{r[2]},{r[3]:.6f},{r[4]:.6e},{r[5]:.6e}\n")
    print(run([UMBRA, "bench", "accuracy", "--extra-curves", MT_CSV, "--scenes", a.scenes,
               "--reference-spp", a.reference_spp, "--budget", a.umbra_budget,
               "--threads", a.threads]))
    print(f"\nRun {started:%Y-%m-%d %H:%M}, {a.threads} threads, "
          f"{os.cpu_count()} cores; load average {os.getloadavg()[0]:.2f} at the end.")
    print("\n".join(notes))
    print()
    print(ratios(scenes))


if __name__ == "__main__":
    main()
