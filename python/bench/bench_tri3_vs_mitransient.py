"""Umbra tri3 (deterministic three-bounce) vs mitransient 1.3.1 (llvm_ad_mono): the time each
needs to reach tri3's error, three-bounce only.

Run from the repository root:

    .venv/bin/python python/bench/bench_tri3_vs_mitransient.py

It needs target/release/umbra (`cargo build --release`) and the .venv of the cross-validation
suite (mitransient 1.3.1; see bench_vs_mitransient.py, whose renderer wrappers, reference and
error definition it reuses). Options: --cases T-single,arc (substrings), --threads,
--time-cap (seconds per ladder render), --tri3-args "--visibility subtriangle ...",
--no-write (do not touch BENCHMARKS.md).

Per case (T.xml / arc.xml x single / confocal; `-D max_depth=3 -D filter_bounces=2`; mitransient
runs the XML's techniques: laser sampling + hidden-geometry sampling):

1. Reference: Umbra `--model mc3`, 8 seeds x 32768 spp. Its own variance
   (spread of the seeds) is subtracted from every squared error, as in bench_vs_mitransient.py:
   e^2 = (||H - H_ref||^2 - sum Var(H_ref)) / ||mu||^2, relative L2 over all bins at full time
   resolution (and with 8 bins summed).
2. tri3 (default options unless --tri3-args): rendered 3 times spread over the case (before,
   during and after the ladders); time = median CLI wall clock (process, XML parse, BVH build,
   subdivision, render, .npy write). The in-process time (BVH + subdivision + render) is
   recovered from the summary line (pairs / pairs-per-second). Its error e_tri3 against the
   reference, with a jackknife (leave one reference seed out) standard error, since tri3's bias
   is of the order of the reference's own noise. If e_tri3^2 is not > 2 standard errors above 0
   the target is the upper bound sqrt(e^2 + 2 se), marked "<=" (this favours the Monte Carlo
   renderers). Also: tri3's discretisation error alone, against tri3 at --fine-subdivision.
3. Ladders: mitransient and Umbra mc3 at spp 1024, 2048, ... interleaved rung by rung (2 seeds
   per rung while a render takes < 3 s, then 1), each stops at the first rung whose error is below
   the target or when the next rung would exceed --time-cap seconds. mitransient's time excludes
   scene loading and JIT compilation (bench_vs_mitransient.Mitransient); mc3's time is the whole
   CLI process. Fit log e = c + q log t over the last 4 rungs. Time to the target: log-log
   interpolation between rungs if the ladder reached it ("measured"), else the fit extrapolated
   ("extrapolated", with the factor beyond the last rung's time and the slope q; -1/2 for
   independent samples). Cross-check insensitive to timing noise: spp needed from a fit
   log e = c' + p log spp over the same rungs, times the median time per spp of the last 3 rungs.
4. Ratio = tri3's time / the other renderer's time to tri3's error (and its inverse, the speed-up).
"""
from __future__ import annotations

import argparse
import datetime
import math
import os
import platform
import re
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_vs_mitransient as bvm  # noqa: E402  (also sets up mtutil's path)

ROOT = bvm.ROOT
SCENES = bvm.SCENES
BENCH_MD = bvm.BENCH_MD
COARSE = bvm.COARSE
PARAMS = dict(max_depth=3, filter_bounces=2)          # three-bounce only
CASES = [("T", "single"), ("T", "confocal"), ("arc", "single"), ("arc", "confocal")]
REF_SPP = {"T": 1 << 15, "arc": 1 << 15}
REF_SEEDS = 8
SPP_START = 1 << 10
SPP_MAX = 1 << 20
TWO_SEEDS_BELOW_S = 3.0
FIT_RUNGS = 4
TRI3_REPS = 3
MT = "mitransient"
MC3 = "Umbra mc3"
BEGIN = "<!-- BEGIN bench_tri3_vs_mitransient (generated) -->"
END = "<!-- END bench_tri3_vs_mitransient -->"

log = bvm.log


def coarse(H):
    return H.reshape(*H.shape[:-1], -1, COARSE).sum(-1)


def err2_coarse(ref, H):
    d = coarse(H.astype(np.float64)) - ref.Hc
    return (float((d * d).sum()) - ref.var_sum_c) / ref.norm2_c


def signed_sqrt(x):
    return math.copysign(math.sqrt(abs(x)), x)


def jackknife(renders, fn):
    """fn(Ref) for the full reference and the jackknife standard error over its seeds."""
    full = fn(bvm.Ref(renders))
    k = len(renders)
    th = np.array([fn(bvm.Ref(renders[:i] + renders[i + 1:])) for i in range(k)])
    return full, math.sqrt((k - 1) / k * float(((th - th.mean()) ** 2).sum()))


class Tri3Runner:
    def __init__(self, binary: Path, workdir: Path, threads: int):
        self.bin, self.dir, self.threads, self.n = binary, workdir, threads, 0

    def render(self, xml, params, args):
        self.n += 1
        out = self.dir / f"t{self.n}.npy"
        cmd = [str(self.bin), "render", str(xml), "-o", str(out), "--model", "tri3",
               "--threads", str(self.threads), "-q", "--no-preview", *args]
        for k, v in params.items():
            cmd += ["-D", f"{k}={v}"]
        t0 = time.perf_counter()
        r = subprocess.run(cmd, capture_output=True, text=True)
        dt = time.perf_counter() - t0
        if r.returncode != 0:
            raise RuntimeError(f"umbra failed: {' '.join(cmd)}\n{r.stdout}\n{r.stderr}")
        line = (r.stdout + r.stderr).strip().splitlines()[-1]
        m = re.search(r"\[([0-9, ]+)\].*?(\d+) sub-triangles.* in ([0-9.]+) s: ([0-9.]+) M pairs/s", line)
        inner, subtri = float("nan"), 0
        if m:
            shape = [int(x) for x in m.group(1).split(",")]
            subtri = int(m.group(2))
            meas = int(np.prod(shape[:-1]))
            rate = float(m.group(4))
            inner = meas * subtri / (rate * 1e6) if rate > 0 else float(m.group(3))
        H = np.load(out).astype(np.float64)
        out.unlink()
        return H, dt, inner, subtri, line


def fit_time(ts, es):
    """log e = c + q log t over the last FIT_RUNGS rungs."""
    pts = [(t, e) for t, e in zip(ts, es) if t > 0 and e > 0][-FIT_RUNGS:]
    if len(pts) < 2:
        return float("nan"), float("nan")
    lt, le = np.log([p[0] for p in pts]), np.log([p[1] for p in pts])
    q = float(np.polyfit(lt, le, 1)[0])
    c = float(np.mean(le - q * lt))
    return c, q


def time_to(r, target):
    ts, es = [g["t"] for g in r["rungs"]], [g["err"] for g in r["rungs"]]
    c, q = fit_time(ts, es)
    r["fit_c"], r["slope"] = c, q
    if min(es) <= target:
        r["t_target"] = bvm.interp_time(ts, es, target)
        if not np.isfinite(r["t_target"]):          # reached at the first rung
            r["t_target"] = ts[0] * (es[0] / target) ** (1 / q) if q < 0 else ts[0]
        r["how"] = "measured (interp.)"
        r["extrap"] = 1.0
    elif np.isfinite(q) and q < -0.05:
        r["t_target"] = math.exp((math.log(target) - c) / q)
        r["extrap"] = r["t_target"] / ts[-1]
        r["how"] = f"**extrapolated** x{r['extrap']:.3g} beyond the last rung's time"
    else:
        r["t_target"], r["extrap"], r["how"] = float("nan"), float("nan"), "no fit (error not falling)"
    # cross-check, robust to timing noise: log e = c' + p log spp over the same rungs (no timing
    # in it), times the time per spp of the last 3 rungs (median)
    spps = [g["spp"] for g in r["rungs"]]
    pts = [(s, e) for s, e in zip(spps, es) if e > 0][-FIT_RUNGS:]
    p = float(np.polyfit(np.log([x[0] for x in pts]), np.log([x[1] for x in pts]), 1)[0]) if len(pts) >= 2 else float("nan")
    cs = float(np.mean(np.log([x[1] for x in pts]) - p * np.log([x[0] for x in pts]))) if len(pts) >= 2 else float("nan")
    per_spp = float(np.median([g["t"] / g["spp"] for g in r["rungs"][-3:]]))
    r["slope_spp"] = p
    r["t_spp"] = math.exp((math.log(target) - cs) / p) * per_spp if np.isfinite(p) and p < -0.05 else float("nan")


def run_case(scene, capture, umbra, tri3, mt, args):
    case = f"{scene}-{capture}"
    xml = SCENES / f"{scene}.xml"
    params = {"capture_type": capture, **PARAMS}
    load0 = bvm.loadavg()
    log(f"\n=== {case}  (load {load0})")
    t_case = time.perf_counter()
    tri3_args = shlex.split(args.tri3_args)

    # 1. reference
    ref_spp = REF_SPP[scene]
    t0 = time.perf_counter()
    renders = [umbra.render(xml, params, ref_spp, 1_000_000 + s, ["--model", "mc3"])[0].astype(np.float64)
               for s in range(REF_SEEDS)]
    t_ref = time.perf_counter() - t0
    ref = bvm.Ref(renders)
    log(f"reference: mc3 {REF_SEEDS} x {ref_spp} spp in {t_ref:.1f} s, own rel. error {ref.rel_err:.4%} "
        f"(8 bins summed: {math.sqrt(ref.var_sum_c / ref.norm2_c):.4%})")

    # 2. tri3: error (deterministic: checked over the timed renders) and discretisation error
    tri = dict(t=[], inner=[], H=[])

    def tri3_time():
        H, dt, inner, subtri, line = tri3.render(xml, params, tri3_args)
        tri["t"].append(dt)
        tri["inner"].append(inner)
        tri["H"].append(H)
        tri["subtri"], tri["line"] = subtri, line
        log(f"  tri3: {dt:.3f} s wall, {inner:.4f} s in-process  | {line}")

    tri3_time()
    T = tri["H"][0]
    e2, se2 = jackknife(renders, lambda r: r.err2(T))
    e2c, se2c = jackknife(renders, lambda r: err2_coarse(r, T))
    Hf = tri3.render(xml, params, tri3_args + ["--subdivision", str(args.fine_subdivision)])
    disc = float(np.sqrt(((T - Hf[0]) ** 2).sum() / (Hf[0] ** 2).sum()))
    disc_c = float(np.sqrt(((coarse(T) - coarse(Hf[0])) ** 2).sum() / (coarse(Hf[0]) ** 2).sum()))
    ef2 = jackknife(renders, lambda r: r.err2(Hf[0]))
    total_ratio = float(T.sum() / ref.H.sum())
    significant = e2 - 2 * se2 > 0
    target = math.sqrt(e2) if significant else math.sqrt(max(e2, 0.0) + 2 * se2)
    log(f"tri3 error: {signed_sqrt(e2):.4%} (e^2 = {e2:.3e} +- {se2:.1e}; "
        f"{'significant' if significant else 'NOT significant vs reference noise: target = upper bound'}), "
        f"8 bins: {signed_sqrt(e2c):.4%} (e^2 +- {se2c:.1e}); discretisation vs subdivision "
        f"{args.fine_subdivision}: {disc:.4%} (8 bins {disc_c:.4%}), {Hf[3]} sub-triangles; that render's "
        f"error vs reference {signed_sqrt(ef2[0]):.4%}; total / ref {total_ratio:.5f}; target {target:.4%}")

    # 3. ladders, interleaved
    mt_load = mt.load(xml, params)
    rs = {MT: dict(rungs=[], done=False), MC3: dict(rungs=[], done=False)}

    def render(name, spp, seed):
        if name == MT:
            H, dt, _ = mt.render(spp, seed)
            return H, dt
        H, dt, _ = umbra.render(xml, params, spp, seed, ["--model", "mc3"])
        return H, dt

    spp, rung = SPP_START, 0
    while spp <= SPP_MAX and not all(r["done"] for r in rs.values()):
        active = [n for n in rs if not rs[n]["done"]]
        nseeds = {n: (2 if not rs[n]["rungs"] or 2 * rs[n]["rungs"][-1]["t"] < TWO_SEEDS_BELOW_S else 1)
                  for n in active}
        res = {n: dict(e2=[], t=[]) for n in active}
        for k in range(max(nseeds.values())):
            order = active if (rung + k) % 2 == 0 else active[::-1]
            for n in order:
                if k >= nseeds[n]:
                    continue
                H, dt = render(n, spp, 1000 * rung + k)
                res[n]["e2"].append(ref.err2(H))
                res[n]["t"].append(dt)
        for n in active:
            r, d = rs[n], res[n]
            e = math.sqrt(max(float(np.mean(d["e2"])), 1e-30))
            t = float(np.median(d["t"]))
            r["rungs"].append(dict(spp=spp, err=e, t=t, n=len(d["t"])))
            log(f"  {n:12s} spp {spp:7d}  err {e:.4%}  t {t:7.3f} s  ({len(d['t'])} seed(s): "
                f"{', '.join(f'{x:.2f}' for x in d['t'])})")
            if e <= target or 2 * t > args.time_cap:
                r["done"] = True
        if rung == 1:
            tri3_time()
        spp *= 2
        rung += 1
    while len(tri["t"]) < TRI3_REPS:
        tri3_time()
    det = all(np.array_equal(tri["H"][0], H) for H in tri["H"][1:])

    for r in rs.values():
        time_to(r, target)
    t_case = time.perf_counter() - t_case
    load1 = bvm.loadavg()
    t3 = float(np.median(tri["t"]))
    out = dict(case=case, scene=scene, capture=capture, ref=ref, ref_spp=ref_spp, t_ref=t_ref,
               e2=e2, se2=se2, e2c=e2c, se2c=se2c, significant=significant, target=target, disc=disc,
               disc_c=disc_c, fine_subtri=Hf[3], fine_err2=ef2, total_ratio=total_ratio,
               t3=t3, t3_all=tri["t"], t3_inner=float(np.median(tri["inner"])), subtri=tri["subtri"],
               det=det, rs=rs, mt_load=mt_load, t_case=t_case, load0=load0, load1=load1)
    for n, r in rs.items():
        log(f"  {n}: time to {target:.4%}: {bvm.fmt_t(r['t_target'])} ({how(r)}); "
            f"tri3 / it = {t3 / r['t_target']:.2e}")
    log(f"case {case} done in {t_case:.0f} s (load {load1})")
    return out


def pct(x, nd=2):
    return f"{100 * x:.{nd}f} %"


def fmt_t(x):
    if not np.isfinite(x):
        return "n/a"
    if x < 1:
        return f"{x * 1e3:.0f} ms"
    return bvm.fmt_t(x) if x < 100 else f"{x:.0f} s"


def how(r):
    return (f"{r['how']}, slope q = {r['slope']:.2f}; cross-check via error vs spp "
            f"(p = {r['slope_spp']:.2f}) x time per spp: {fmt_t(r['t_spp'])}")


def summary_table(cases):
    lines = ["| case | tri3 time (CLI, median of 3) | tri3 in-process | tri3 error (full res.) | "
             "tri3 error (8 bins) | mitransient: time to tri3's error | how | "
             "**ratio tri3 / mitransient** | mc3: time to tri3's error | how | **ratio tri3 / mc3** |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for c in cases:
        mt, mc = c["rs"][MT], c["rs"][MC3]
        err = (f"{pct(c['target'], 3)} +- {pct(c['se2'] / (2 * c['target']), 3)}" if c["significant"]
               else f"<= {pct(c['target'], 3)} (not resolved)")
        errc = f"{pct(signed_sqrt(c['e2c']), 3)} +- {pct(c['se2c'] / (2 * max(math.sqrt(abs(c['e2c'])), 1e-4)), 3)}"
        lines.append(
            f"| {c['case']} | {fmt_t(c['t3'])} | {fmt_t(c['t3_inner'])} | {err} | {errc} | "
            f"{fmt_t(mt['t_target'])} | {how(mt)} | "
            f"**{c['t3'] / mt['t_target']:.1e}** (speed-up {mt['t_target'] / c['t3']:.0f}x) | "
            f"{fmt_t(mc['t_target'])} | {how(mc)} | "
            f"**{c['t3'] / mc['t_target']:.1e}** (speed-up {mc['t_target'] / c['t3']:.0f}x) |")
    return "\n".join(lines) + "\n"


def case_detail(c):
    rs = c["rs"]
    longest = max((r["rungs"] for r in rs.values()), key=len)
    n = len(longest)
    lines = [f"### {c['case']}", "",
             f"Load average {c['load0']} before, {c['load1']} after; case took {c['t_case']:.0f} s. "
             f"Reference: mc3, {REF_SEEDS} x {c['ref_spp']} spp ({c['t_ref']:.0f} s), own rel. error "
             f"{pct(c['ref'].rel_err, 3)} (8 bins: {pct(math.sqrt(c['ref'].var_sum_c / c['ref'].norm2_c), 3)}), "
             f"subtracted in quadrature. tri3: {c['subtri']} sub-triangles, wall clock "
             f"{', '.join(f'{x * 1e3:.0f}' for x in c['t3_all'])} ms, in-process {c['t3_inner'] * 1e3:.1f} ms, "
             f"output {'identical over the renders' if c['det'] else '**NOT identical over the renders**'}; "
             f"e^2 = {c['e2']:.2e} +- {c['se2']:.1e} (jackknife), total / reference {c['total_ratio']:.5f}; "
             f"discretisation alone (vs tri3 at subdivision {ARGS.fine_subdivision}, {c['fine_subtri']} "
             f"sub-triangles): {pct(c['disc'], 3)} (8 bins {pct(c['disc_c'], 3)}); that fine render's error "
             f"vs the reference: {pct(signed_sqrt(c['fine_err2'][0]), 3)} (e^2 +- {c['fine_err2'][1]:.1e}). "
             f"mitransient scene load {c['mt_load']:.2f} s (excluded).", "",
             "| renderer | " + " | ".join(f"{g['spp']} spp" for g in longest) + " |",
             "|---|" + "---|" * n]
    for name, r in rs.items():
        cells = [f"{pct(g['err'])} / {g['t']:.2f} s" + ("" if g["n"] > 1 else " (1 seed)") for g in r["rungs"]]
        cells += [""] * (n - len(cells))
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def write_md(text):
    block = f"{BEGIN}\n{text}\n{END}\n"
    old = BENCH_MD.read_text() if BENCH_MD.exists() else "# Benchmarks\n"
    if BEGIN in old and END in old:
        pre, rest = old.split(BEGIN, 1)
        post = rest.split(END, 1)[1]
        BENCH_MD.write_text(pre + block + post.lstrip("\n"))
    else:
        BENCH_MD.write_text(old.rstrip() + "\n\n" + block)


ARGS = None


def main():
    global ARGS
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cases", default="", help="comma-separated substrings selecting cases")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--time-cap", type=float, default=16.0,
                    help="a ladder stops when its next render would take longer (seconds)")
    ap.add_argument("--tri3-args", default="", help="extra tri3 CLI options, e.g. '--visibility subtriangle'")
    ap.add_argument("--fine-subdivision", type=float, default=0.02)
    ap.add_argument("--umbra", default=str(ROOT / "target" / "release" / "umbra"))
    ap.add_argument("--no-write", action="store_true")
    args = ARGS = ap.parse_args()

    sel = [c for c in CASES if not args.cases or any(tok in "-".join(c) for tok in args.cases.split(","))]
    t_start = time.perf_counter()
    load0 = bvm.loadavg()
    src = Path(args.umbra)
    if not src.exists():
        sys.exit(f"{src} not found: cargo build --release")
    work = Path(tempfile.mkdtemp(prefix="umbra-tri3-bench-"))
    binary = work / "umbra"                    # snapshot: a concurrent cargo build cannot swap it
    shutil.copy2(src, binary)
    bin_time = datetime.datetime.fromtimestamp(src.stat().st_mtime).strftime("%Y-%m-%d %H:%M")
    head = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True,
                          text=True).stdout.strip()
    dirty = [ln[3:] for ln in subprocess.run(["git", "-C", str(ROOT), "status", "--porcelain", "--untracked-files=no"],
                                             capture_output=True, text=True).stdout.splitlines()
             if not ln[3:].startswith(("python/bench/", "BENCHMARKS.md"))]
    umbra = bvm.Umbra(binary, work, args.threads)
    tri3 = Tri3Runner(binary, work, args.threads)
    mt = bvm.Mitransient(args.threads)
    log(f"load average at start: {load0}; {os.cpu_count()} CPUs; Umbra binary built {bin_time} (HEAD {head})")
    cases = []
    try:
        for sc, cap in sel:
            cases.append(run_case(sc, cap, umbra, tri3, mt, args))
    finally:
        shutil.rmtree(work, ignore_errors=True)
    t_total = time.perf_counter() - t_start
    load1 = bvm.loadavg()
    cpu = "unknown CPU"
    try:
        cpu = next(l.split(":", 1)[1].strip() for l in open("/proc/cpuinfo") if l.startswith("model name"))
    except Exception:
        pass
    import drjit
    import mitsuba
    tri3_opts = args.tri3_args or "defaults: --visibility centroid, --subdivision 0.15"
    head_txt = f"""## tri3 vs mitransient: time to tri3's error

Reproduce (from the repository root, after `cargo build --release`):

    .venv/bin/python python/bench/bench_tri3_vs_mitransient.py

Run {datetime.datetime.now().strftime('%Y-%m-%d %H:%M')}, {t_total / 60:.1f} min, on {platform.node() or 'this machine'}: {os.cpu_count()} cores ({cpu}),
{args.threads} threads for every renderer. Load average (1/5/15 min) {load0} at the start, {load1} at the end
(the machine is shared; renders are interleaved). Umbra binary built {bin_time}, HEAD {head}{' (uncommitted changes: ' + ' '.join(dirty) + ')' if dirty else ''};
mitransient {mt.mitr.__version__}, Mitsuba {mitsuba.__version__}, Dr.Jit {drjit.__version__}, llvm_ad_mono.

Three-bounce only (`-D max_depth=3 -D filter_bounces=2`) on `python/validation/scenes/{{T,arc}}.xml`
(16 x 16 scan points x 256 bins). tri3: `--model tri3` ({tri3_opts}), deterministic. Error = relative L2
over all bins against an Umbra `--model mc3` reference ({REF_SEEDS} seeds x {', '.join(f'{v} spp ({k})' for k, v in REF_SPP.items())}),
the reference's own variance subtracted in quadrature; tri3's error is +- a jackknife standard error over the
reference seeds (tri3's bias is of the order of the reference's noise), "8 bins" sums 8 bins first. tri3 time:
CLI wall clock (whole process), median of 3 renders spread over the case; in-process = BVH + subdivision + render.
mitransient (XML techniques: laser + hidden-geometry sampling; time excludes scene load and JIT compile) and
Umbra mc3 (CLI wall clock) run spp ladders from {SPP_START}, doubling, interleaved, until the error is below
tri3's or the next render would exceed {args.time_cap:.0f} s; the time to tri3's error is interpolated on the
ladder if it got there, else extrapolated along a fit log e = c + q log t over the last {FIT_RUNGS} rungs
(q = -1/2 for independent samples). Cross-check, insensitive to timing noise (the machine is shared): the spp
needed from a fit log e = c' + p log spp over the same rungs, times the median time per spp of the last 3 rungs.
**Extrapolated times assume the error keeps falling at the fitted rate** (no bias floor above tri3's error).
Ratio = tri3's time / the other renderer's time to tri3's error (small = tri3 faster); speed-up = its inverse.
"""
    body = [head_txt, summary_table(cases), "Ladders: error / time (median wall clock) per spp:", ""]
    body += [case_detail(c) for c in cases]
    text = "\n".join(body)
    print("\n" + text)
    if not args.no_write:
        write_md(text)
        log(f"wrote {BENCH_MD}")


if __name__ == "__main__":
    main()
