"""Umbra vs mitransient 1.3.1 (llvm_ad_mono): samples/s and time to 3 % relative error.

Run from the repository root:

    .venv/bin/python python/bench/bench_vs_mitransient.py

It needs target/release/umbra (`cargo build --release`) and the .venv of the cross-validation
suite (mitransient 1.3.1, Mitsuba 3.9.1, Dr.Jit 1.5.0, LLVM 19; see DESIGN.md section 7), plus
matplotlib for the chart (optional). Options: --cases T-single-3b,arc (substrings), --threads,
--target-err, --stop-err, --no-write (do not touch BENCHMARKS.md / the PNG).

What it does, per case (scene x capture x {3b: three-bounce only, mb: up to 6 bounces}):

1. A converged reference: Umbra, 4 seeds x 2^15 spp (2^14 for arc; mc3 for 3b, path with MIS
   of BSDF + hidden-geometry sampling for mb). Its own variance (estimated from the spread of
   the seeds) is subtracted from every squared error below, so the errors are those against
   the true expectation, not against a noisy reference.
2. Ladders of spp (powers of two from 512), 2 seeds per rung (distinct everywhere),
   renderers interleaved (A B C, B C A) so background load hits all alike. Each renderer stops
   after its first rung whose error is below --stop-err (default: the target; step 4 checks
   the fit at the spp it predicts).
   - mitransient: the scene is loaded once per case; render time = wall clock of mi.render
     (tracing + kernel launch + develop + np.array) minus that render's JIT compile time
     (codegen + LLVM backend, from Dr.Jit's kernel history: a new spp compiles a new kernel).
   - Umbra: wall clock of the whole CLI process (XML parse, BVH build, render, npy write).
   Time per rung = median over the seeds.
3. Relative L2 error e = ||H - H_ref|| / ||H_ref|| (all bins, full time resolution), RMS
   over seeds, reference variance subtracted. Local fit log e = c + p log spp over the last
   3 rungs below 10 % (independent samples: p = -1/2; Umbra's scrambled Sobol' samples can
   converge faster, so p is fitted); spp* = the spp where the fit crosses the target.
4. Final timing: each renderer renders spp* three times, interleaved A B C, C B A, A B C:
   t* = median wall clock, e* = RMS error of those renders. Time to target =
   t* (e* / target)^(-1/p) (a local correction, small when the fit holds).
   Then samples/s of every renderer at one spp (2^14 for T, 2^13 for arc; 2 interleaved
   renders, median), and the fixed cost of a 1-spp render.
5. Consistency: all the ladder renders of each renderer, combined (weighted by spp), against
   the reference: relative L2 against the value expected from noise alone (per-render
   variances estimated from the seeds of each rung), at full and at
   coarse (8 bins summed) time resolution, and the total's z-score. If mitransient and the
   reference disagree beyond noise, the case is flagged as a FINDING (no number is picked).
"""
from __future__ import annotations

import argparse
import datetime
import math
import os
import platform
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "python" / "validation"))
import mtutil  # noqa: E402

SCENES = ROOT / "python" / "validation" / "scenes"
BENCH_MD = ROOT / "BENCHMARKS.md"
CHART = ROOT / "python" / "bench" / "error_vs_time.png"

KINDS = {
    # XML <default> overrides (mitransient numbering with laser sampling on)
    "3b": dict(max_depth=3, filter_bounces=2),
    "mb": dict(max_depth=6, filter_bounces=-1),
}
# Umbra variants per kind: (label, extra CLI args)
UMBRA_VARIANTS = {
    "3b": [("Umbra path, XML techniques (laser + HGS)", []),
           ("Umbra path, MIS (BSDF + HGS) + laser", ["--bsdf-sampling", "true"]),
           ("Umbra mc3 (laser + HGS)", ["--model", "mc3"])],
    "mb": [("Umbra path, XML techniques (laser + HGS)", []),
           ("Umbra path, MIS (BSDF + HGS) + laser", ["--bsdf-sampling", "true"]),
           # The same without the roulette before rr_bounces that a pilot picks by
           # default (transport::roulette): what the roulette buys, in the same run.
           ("Umbra path, MIS + laser, no early roulette (--rr-early-survival 1)",
            ["--bsdf-sampling", "true", "--rr-early-survival", "1"])],
}
MT_LABEL = "mitransient llvm_ad_mono (laser + HGS)"
# reference: (Umbra args, spp per seed, seeds)
REF = {
    "3b": (["--model", "mc3"], 1 << 15, 4),
    "mb": (["--bsdf-sampling", "true"], 1 << 15, 4),
}
REF_SPP_SCALE = {"T": 1.0, "arc": 0.5}
THROUGHPUT_SPP = {"T": 1 << 14, "arc": 1 << 13}   # samples/s of all renderers at one spp   # arc's multi-bounce paths cost ~3x more
CASES = [("T", "single", "3b"), ("T", "confocal", "3b"), ("T", "single", "mb"),
         ("T", "confocal", "mb"), ("arc", "single", "mb"), ("arc", "confocal", "mb")]
SEEDS = 2
FINAL_REPS = 3
SPP_START = 1 << 9
SPP_MAX = 1 << 18
FIT_MAX_ERR = 0.10
FIT_RUNGS = 3
COARSE = 8


def log(*a):
    print(*a, flush=True)


def loadavg() -> str:
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


# ----------------------------------------------------------------------------- renderers

class Umbra:
    def __init__(self, binary: Path, workdir: Path, threads: int):
        self.bin, self.dir, self.threads = binary, workdir, threads
        self.n = 0

    def render(self, xml: Path, params: dict, spp: int, seed: int, args: list[str]):
        self.n += 1
        out = self.dir / f"u{self.n}.npy"
        cmd = [str(self.bin), "render", str(xml), "-o", str(out), "--spp", str(spp),
               "--seed", str(seed), "--threads", str(self.threads), "-q", "--no-preview", *args]
        for k, v in params.items():
            cmd += ["-D", f"{k}={v}"]
        t0 = time.perf_counter()
        r = subprocess.run(cmd, capture_output=True, text=True)
        dt = time.perf_counter() - t0
        if r.returncode != 0:
            raise RuntimeError(f"umbra failed: {' '.join(cmd)}\n{r.stdout}\n{r.stderr}")
        m = re.search(r" in ([0-9.]+) s", r.stdout + r.stderr)
        inner = float(m.group(1)) if m else float("nan")
        H = np.load(out)
        out.unlink()
        return H, dt, inner


class Mitransient:
    def __init__(self, threads: int):
        self.mi, self.mitr = mtutil.setup(threads)
        self.scene = None
        self.key = None

    def load(self, xml: Path, params: dict):
        key = (str(xml), tuple(sorted(params.items())))
        if key != self.key:
            t0 = time.perf_counter()
            self.scene = mtutil.load_xml(xml, **params)
            self.load_s = time.perf_counter() - t0
            self.key = key
        return self.load_s

    def render(self, spp: int, seed: int):
        """Returns (H, wall seconds minus JIT compile time, JIT compile seconds). A new spp
        compiles a new kernel (~0.4 s of LLVM backend time, or a load from Dr.Jit's disk
        cache); the compile time of this render's kernels is read from Dr.Jit's kernel history
        and subtracted, so every render can be timed (checked: first render at a new spp minus
        its compile time = a second render at that spp, to ~1 %)."""
        import drjit as dr
        dr.set_flag(dr.JitFlag.KernelHistory, True)
        dr.kernel_history()                                   # clears the history
        t0 = time.perf_counter()
        _, transient = self.mi.render(self.scene, spp=spp, seed=seed)
        H = mtutil.to_numpy(transient)
        dt = time.perf_counter() - t0
        hist = [h for h in dr.kernel_history() if "cache_hit" in h]
        comp = sum(h.get("codegen_time", 0.0) + h.get("backend_time", 0.0) for h in hist) / 1e3
        return H, dt - comp, comp


# ----------------------------------------------------------------------------- statistics

class Ref:
    def __init__(self, renders: list[np.ndarray]):
        R = np.stack([r.astype(np.float64) for r in renders])
        self.H = R.mean(0)
        self.var_sum = R.var(0, ddof=1).sum() / len(R)        # E||H_ref - mu||^2
        self.norm2 = max(float((self.H ** 2).sum()) - self.var_sum, 1e-300)  # ||mu||^2 estimate
        self.rel_err = math.sqrt(self.var_sum / self.norm2)
        Rc = R.reshape(*R.shape[:-1], -1, COARSE).sum(-1)
        self.Hc = Rc.mean(0)
        self.var_sum_c = Rc.var(0, ddof=1).sum() / len(R)
        self.norm2_c = float((self.Hc ** 2).sum()) - self.var_sum_c
        P = R.sum(-1)                                          # per-scan-point totals
        self.total = float(P.mean(0).sum())
        self.total_se = math.sqrt(P.var(0, ddof=1).sum() / len(R))

    def err2(self, H: np.ndarray) -> float:
        """Squared relative L2 error against the expectation (reference variance removed)."""
        d = H.astype(np.float64) - self.H
        return (float((d * d).sum()) - self.var_sum) / self.norm2


def fit_local(spps, errs):
    """log e = c + p log spp, least squares over the last (lowest-error) FIT_RUNGS rungs with
    e < FIT_MAX_ERR. Independent samples give p = -1/2; Umbra's scrambled-Sobol' samples can
    converge faster, so p is fitted, not assumed (falls back to -1/2 with one point or p >= 0)."""
    pts = [(s, e) for s, e in zip(spps, errs) if 0 < e < FIT_MAX_ERR][-FIT_RUNGS:]
    if not pts:
        pts = [min(zip(spps, errs), key=lambda q: q[1])]
    ls = np.log([q[0] for q in pts])
    le = np.log([q[1] for q in pts])
    p = float(np.polyfit(ls, le, 1)[0]) if len(pts) >= 2 else -0.5
    if not p < -0.05:
        p = -0.5
    c = float(np.mean(le - p * ls))
    return c, p


def spp_for(c, p, target):
    return max(1, int(math.ceil(math.exp((math.log(target) - c) / p))))


def interp_time(ts, errs, target):
    """Log-log interpolation of (time, error) at the target (nan if not bracketed)."""
    for (t0, e0), (t1, e1) in zip(zip(ts, errs), zip(ts[1:], errs[1:])):
        if e0 >= target >= e1 and e0 > 0 and e1 > 0 and e0 != e1:
            f = (math.log(e0) - math.log(target)) / (math.log(e0) - math.log(e1))
            return math.exp(math.log(t0) + f * (math.log(t1) - math.log(t0)))
    return float("nan")


# ----------------------------------------------------------------------------- one case

def run_case(scene, capture, kind, umbra, mt, args):
    case = f"{scene}-{capture}-{kind}"
    xml = SCENES / f"{scene}.xml"
    params = {"capture_type": capture, **KINDS[kind]}
    n_scan = 16 * 16
    load0 = loadavg()
    log(f"\n=== {case}  (load {load0})")
    t_case = time.perf_counter()

    # 1. reference
    ref_args, ref_spp, ref_seeds = REF[kind]
    ref_spp = int(ref_spp * REF_SPP_SCALE.get(scene, 1.0))
    t0 = time.perf_counter()
    ref = Ref([umbra.render(xml, params, ref_spp, 1_000_000 + s, ref_args)[0] for s in range(ref_seeds)])
    t_ref = time.perf_counter() - t0
    log(f"reference: Umbra {' '.join(ref_args)} {ref_seeds} x {ref_spp} spp in {t_ref:.1f} s, "
        f"rel. error {ref.rel_err:.4f}, total {ref.total:.6g} +- {ref.total_se / ref.total:.2%}")

    # renderers: name -> dict
    rs = {MT_LABEL: dict(kind="mt", args=None)}
    for label, a in UMBRA_VARIANTS[kind]:
        rs[label] = dict(kind="umbra", args=a)
    for r in rs.values():
        r.update(rungs=[], done=False, sum_H=None, sum_spp=0, vars=[])
    mt_load = mt.load(xml, params)

    def render(r, spp, seed):
        if r["kind"] == "mt":
            return mt.render(spp, seed)
        return umbra.render(xml, params, spp, seed, r["args"])

    # 2. ladders, interleaved
    names = list(rs)
    spp = SPP_START
    rung = 0
    while spp <= SPP_MAX and not all(r["done"] for r in rs.values()):
        active = [n for n in names if not rs[n]["done"]]
        res = {n: dict(H=[], t=[], inner=[], e2=[]) for n in active}
        for k in range(SEEDS):
            order = active[k % len(active):] + active[:k % len(active)]
            for n in order:
                seed = 1000 * rung + k          # distinct seeds per rung: independent renders
                H, dt, inner = render(rs[n], spp, seed)
                d = res[n]
                d["e2"].append(ref.err2(H))
                d["t"].append(dt)
                d["inner"].append(inner)
                d["H"].append(H.astype(np.float64))
        for n in active:
            r, d = rs[n], res[n]
            e = math.sqrt(max(np.mean(d["e2"]), 1e-30))
            t = float(np.median(d["t"]))
            Hs = np.stack(d["H"])
            # variance of one render at this spp (summed over bins), from the spread of the
            # seeds: Umbra's samples are stratified (scrambled Sobol'), so variance need not
            # scale as 1/spp and is kept per rung
            Hc = Hs.reshape(*Hs.shape[:-1], -1, COARSE).sum(-1)
            P = Hs.sum(-1)
            r["vars"].append((spp, len(Hs), Hs.var(0, ddof=1).sum(), Hc.var(0, ddof=1).sum(),
                              P.var(0, ddof=1).sum()))
            add = Hs.sum(0) * spp
            r["sum_H"] = add if r["sum_H"] is None else r["sum_H"] + add
            r["sum_spp"] += spp * len(d["H"])
            r["rungs"].append(dict(spp=spp, err=e, t=t, t_all=d["t"], inner=float(np.median(d["inner"]))))
            log(f"  {n:45s} spp {spp:7d}  err {e:.4f}  t {t:7.3f} s  "
                f"{spp * n_scan / t / 1e6:6.3f} M samples/s  " +
                ("umbra's own render seconds" if r["kind"] == "umbra" else "JIT compile excluded") +
                f" {', '.join(f'{x:.2f}' for x in d['inner'])}")
            if e < args.stop_err:
                r["done"] = True
        spp *= 2
        rung += 1

    # 3. fit, 4. final timing at spp*
    for n, r in rs.items():
        cc, p = fit_local([g["spp"] for g in r["rungs"]], [g["err"] for g in r["rungs"]])
        r["fit_c"], r["slope"] = cc, p
        r["spp_star"] = spp_for(cc, p, args.target_err)
        r["t_interp"] = interp_time([g["t"] for g in r["rungs"]], [g["err"] for g in r["rungs"]],
                                    args.target_err)
        r["final_t"], r["final_e2"] = [], []
    mtn = MT_LABEL
    for rep in range(FINAL_REPS):
        order = names if rep % 2 == 0 else names[::-1]   # A B C, C B A, A B C
        for n in order:
            r = rs[n]
            H, dt, _ = render(r, r["spp_star"], 600_000 + rep)
            r["final_t"].append(dt)
            r["final_e2"].append(ref.err2(H))
    for r in rs.values():
        r["t_star"] = float(np.median(r["final_t"]))
        r["final_err"] = math.sqrt(max(np.mean(r["final_e2"]), 0))
        # time to the target: the measured time, corrected locally (e ~ spp^p, time ~ spp)
        # where the final renders' error missed the target
        r["t_target"] = r["t_star"] * (r["final_err"] / args.target_err) ** (-1 / r["slope"])
        r["off_fit"] = abs(r["final_err"] / args.target_err - 1) > 0.15

    # samples/s at one common spp, 2 interleaved repetitions
    tp_spp = THROUGHPUT_SPP.get(scene, 1 << 13)
    for rep in range(2):
        for n in (names if rep == 0 else names[::-1]):
            r = rs[n]
            r.setdefault("tp_t", []).append(render(r, tp_spp, 700_000 + rep)[1])
    for r in rs.values():
        r["tp"] = tp_spp * n_scan / float(np.median(r["tp_t"]))

    # 5. consistency against the reference
    for n, r in rs.items():
        N = r["sum_spp"]
        Hm = r["sum_H"] / N                                  # spp-weighted mean of all renders
        vm = [sum(k * (sp / N) ** 2 * v[i] for sp, k, *v in r["vars"]) for i in range(3)]
        d2 = float(((Hm - ref.H) ** 2).sum())
        exp2 = vm[0] + ref.var_sum
        Hmc = Hm.reshape(*Hm.shape[:-1], -1, COARSE).sum(-1)
        d2c = float(((Hmc - ref.Hc) ** 2).sum())
        exp2c = vm[1] + ref.var_sum_c
        tot = float(Hm.sum())
        se = math.sqrt(vm[2] + ref.total_se ** 2)
        r["check"] = dict(l2=math.sqrt(d2 / ref.norm2), l2_exp=math.sqrt(exp2 / ref.norm2),
                          l2c=math.sqrt(d2c / ref.norm2_c), l2c_exp=math.sqrt(exp2c / ref.norm2_c),
                          ratio=tot / ref.total, z=(tot - ref.total) / se)
        c = r["check"]
        c["ok"] = c["l2"] <= 1.5 * c["l2_exp"] and c["l2c"] <= 1.5 * c["l2c_exp"]
        c["excess"] = math.sqrt(max(c["l2"] ** 2 - c["l2_exp"] ** 2, 0.0))
    mt_ok = rs[mtn]["check"]["ok"]
    # fixed per-run overhead: Umbra at 1 spp (process + parse + BVH + write), mitransient at 1 spp
    u_over = sorted(umbra.render(xml, params, 1, 0, [])[1] for _ in range(5))
    mt_over = float(np.median([mt.render(1, s)[1] for s in range(3)]))
    t_case = time.perf_counter() - t_case
    load1 = loadavg()
    log(f"case {case} done in {t_case:.0f} s (load {load1})")
    return dict(case=case, scene=scene, capture=capture, kind=kind, ref=ref, ref_args=ref_args,
                ref_spp=ref_spp, ref_seeds=ref_seeds, t_ref=t_ref, rs=rs, mt_ok=mt_ok, mt_load=mt_load,
                u_over=u_over, mt_over=mt_over, n_scan=n_scan, tp_spp=tp_spp, t_case=t_case, load0=load0, load1=load1)


# ----------------------------------------------------------------------------- report

def fmt_t(x):
    return "n/a" if not np.isfinite(x) else (f"{x:.2f} s" if x < 10 else f"{x:.1f} s")


def case_table(c, target):
    rs = c["rs"]
    mt = rs[MT_LABEL]
    n_scan = c["n_scan"]
    # common rung: the largest spp every renderer ran
    common = min(max(g["spp"] for g in r["rungs"]) for r in rs.values())

    def rung(r, spp):
        return next(g for g in r["rungs"] if g["spp"] == spp)

    mt_sps_f = mt["spp_star"] * n_scan / mt["t_star"]
    lines = [f"### {c['case']}",
             "",
             f"Load average {c['load0']} before this case, {c['load1']} after; case took {c['t_case']:.0f} s. "
             f"Reference: Umbra `{' '.join(c['ref_args'])}`, {c['ref_seeds']} x {c['ref_spp']} spp "
             f"({c['t_ref']:.0f} s), its own rel. error {c['ref'].rel_err:.2%} (subtracted in quadrature). "
             f"mitransient scene load {c['mt_load']:.2f} s (excluded); fixed cost of a 1-spp render: "
             f"Umbra process {c['u_over'][2] * 1e3:.0f} ms (min {c['u_over'][0] * 1e3:.0f}, max {c['u_over'][-1] * 1e3:.0f}), mitransient {c['mt_over'] * 1e3:.0f} ms.",
             "",
             f"| renderer / technique | samples/s at {c['tp_spp']} spp | x mt | error at {common} spp | x mt | slope p | "
             f"spp* | time at spp* (median of {FINAL_REPS}) | err at spp* | samples/s at spp* | "
             f"x mt | **time to {target:.0%}** | (ladder interp.) | **speed-up vs mt** |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for n, r in rs.items():
        sps_f = r["spp_star"] * n_scan / r["t_star"]
        lines.append(
            f"| {n} | {r['tp'] / 1e6:.2f} M | {r['tp'] / mt['tp']:.2f} | {rung(r, common)['err']:.2%} | "
            f"{rung(r, common)['err'] / rung(mt, common)['err']:.2f} | {r['slope']:.2f} | "
            f"{r['spp_star']} | {fmt_t(r['t_star'])} "
            f"({', '.join(f'{x:.2f}' for x in r['final_t'])}) | {r['final_err']:.2%}{' (off fit)' if r['off_fit'] else ''} | "
            f"{sps_f / 1e6:.2f} M | {sps_f / mt_sps_f:.2f} | **{fmt_t(r['t_target'])}** | {fmt_t(r['t_interp'])} | "
            f"**{mt['t_target'] / r['t_target']:.2f}x** |")
    nmax = max(len(r["rungs"]) for r in rs.values())
    longest = max((r["rungs"] for r in rs.values()), key=len)
    lines += ["", "Ladder: error (rel. L2 vs reference, RMS over seeds) / time (median wall clock):", "",
              "| renderer | " + " | ".join(f"{g['spp']} spp" for g in longest) + " |",
              "|---|" + "---|" * nmax]
    for n, r in rs.items():
        cells = [f"{g['err']:.2%} / {g['t']:.2f} s" for g in r["rungs"]]
        cells += [""] * (nmax - len(cells))
        lines.append(f"| {n} | " + " | ".join(cells) + " |")
    lines += ["", "Consistency of each renderer's combined ladder renders with the reference "
              "(rel. L2 measured vs expected from noise alone; ok = both within 1.5x; "
              "excess = sqrt(measured^2 - expected^2), a bound on a bias's share of the L2 error):", "",
              "| renderer | spp combined | L2 full | expected | L2 coarse (8 bins) | expected | excess | "
              "total ratio | z | ok |",
              "|---|---|---|---|---|---|---|---|---|---|"]
    for n, r in rs.items():
        k = r["check"]
        lines.append(f"| {n} | {r['sum_spp']} | {k['l2']:.4f} | {k['l2_exp']:.4f} | {k['l2c']:.4f} | "
                     f"{k['l2c_exp']:.4f} | {k['excess']:.4f} | {k['ratio']:.5f} | {k['z']:+.1f} | "
                     f"{'yes' if k['ok'] else '**NO**'} |")
    k = rs[MT_LABEL]["check"]
    if c["mt_ok"] and abs(k["z"]) > 4:
        lines += ["", f"mitransient's total differs from the reference by {k['ratio'] - 1:+.3%} (z = {k['z']:+.1f}): "
                  "significant at this sample count but {:.2f} % of L2 at most (column excess), negligible against "
                  "the target; mitransient's hidden-geometry sampling loses samples near mesh edges "
                  "(notes/mitransient.md, section c.7).".format(100 * k["excess"])]
    if not c["mt_ok"]:
        lines += ["", "**FINDING: mitransient and the Umbra reference disagree beyond noise in this case; "
                  "the time-to-error numbers above are not meaningful until that is resolved.**"]
    return "\n".join(lines) + "\n"


def summary_table(cases, target):
    lines = [f"| case | mitransient: time to {target:.0%} | best Umbra | its time | **speed-up** | its samples/s x mt | "
             f"its error at equal spp x mt | Umbra, XML techniques: speed-up | samples/s x mt | error at equal spp x mt | "
             f"mt agrees with ref |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for c in cases:
        rs = c["rs"]
        mt = rs[MT_LABEL]
        best = min((n for n in rs if n != MT_LABEL), key=lambda n: rs[n]["t_target"])
        xmln = next(n for n in rs if "XML" in n)
        common = min(max(g["spp"] for g in r["rungs"]) for r in rs.values())
        er = lambda r: next(g for g in r["rungs"] if g["spp"] == common)["err"] / \
            next(g for g in mt["rungs"] if g["spp"] == common)["err"]
        lines.append(f"| {c['case']} | {fmt_t(mt['t_target'])} | {best} | {fmt_t(rs[best]['t_target'])} | "
                     f"**{mt['t_target'] / rs[best]['t_target']:.2f}x** | {rs[best]['tp'] / mt['tp']:.2f} | "
                     f"{er(rs[best]):.2f} | {mt['t_target'] / rs[xmln]['t_target']:.2f}x | "
                     f"{rs[xmln]['tp'] / mt['tp']:.2f} | {er(rs[xmln]):.2f} | {'yes' if c['mt_ok'] else '**NO**'} |")
    return "\n".join(lines) + "\n"


def chart(cases, target, path):
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        log("matplotlib not available: no chart")
        return False
    n = len(cases)
    cols = min(n, 2)
    rows = (n + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(6.5 * cols, 4.6 * rows), squeeze=False)
    for ax, c in zip(axes.flat, cases):
        for i, (name, r) in enumerate(c["rs"].items()):
            col = f"C{i}"
            ax.loglog([g["t"] for g in r["rungs"]], [g["err"] for g in r["rungs"]], "o-", color=col,
                      label=name, ms=4)
            ax.loglog([r["t_star"]], [r["final_err"]], "*", color=col, ms=12)
        ax.axhline(target, color="k", lw=0.8, ls="--")
        ax.set_title(c["case"])
        ax.set_xlabel("wall-clock seconds (2 threads)")
        ax.set_ylabel("relative L2 error")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    for ax in list(axes.flat)[n:]:
        ax.axis("off")
    fig.suptitle(f"Error vs time, 16x16 scan x 256 bins (stars: final timed renders at the spp for {target:.0%})",
                 fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    return True


def write_md(text):
    begin, end = "<!-- BEGIN bench_vs_mitransient (generated) -->", "<!-- END bench_vs_mitransient -->"
    block = f"{begin}\n{text}\n{end}\n"
    if BENCH_MD.exists():
        old = BENCH_MD.read_text()
        if begin in old and end in old:
            pre, rest = old.split(begin, 1)
            post = rest.split(end, 1)[1]
            BENCH_MD.write_text(pre + block + post.lstrip("\n"))
            return
        BENCH_MD.write_text(old.rstrip() + "\n\n" + block)
        return
    BENCH_MD.write_text("# Benchmarks\n\n" + block)


# ----------------------------------------------------------------------------- main

def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--cases", default="", help="comma-separated substrings selecting cases")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--target-err", type=float, default=0.03)
    ap.add_argument("--stop-err", type=float, default=0.03)
    ap.add_argument("--umbra", default=str(ROOT / "target" / "release" / "umbra"))
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args()

    sel = [c for c in CASES if not args.cases or any(tok in "-".join(c) for tok in args.cases.split(","))]
    t_start = time.perf_counter()
    load0 = loadavg()
    work = Path(tempfile.mkdtemp(prefix="umbra-bench-"))
    src = Path(args.umbra)
    if not src.exists():
        sys.exit(f"{src} not found: cargo build --release")
    binary = work / "umbra"                    # snapshot: a concurrent cargo build cannot swap it
    shutil.copy2(src, binary)
    bin_time = datetime.datetime.fromtimestamp(src.stat().st_mtime).strftime("%Y-%m-%d %H:%M")
    head = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True,
                          text=True).stdout.strip()
    dirty = [ln[3:] for ln in subprocess.run(["git", "-C", str(ROOT), "status", "--porcelain", "--untracked-files=no"],
                                             capture_output=True, text=True).stdout.splitlines()
             if not ln[3:].startswith(("python/bench/", "BENCHMARKS.md"))]
    umbra = Umbra(binary, work, args.threads)
    mt = Mitransient(args.threads)
    log(f"load average at start: {load0}; {os.cpu_count()} CPUs; Umbra binary built {bin_time} "
        f"(HEAD {head}{', uncommitted: ' + ' '.join(dirty) if dirty else ''})")
    cases = []
    try:
        for sc, cap, kind in sel:
            cases.append(run_case(sc, cap, kind, umbra, mt, args))
    finally:
        shutil.rmtree(work, ignore_errors=True)
    t_total = time.perf_counter() - t_start
    load1 = loadavg()

    cpu = "unknown CPU"
    try:
        cpu = next(l.split(":", 1)[1].strip() for l in open("/proc/cpuinfo") if l.startswith("model name"))
    except Exception:
        pass
    import drjit
    import mitsuba
    tgt = args.target_err
    head_txt = f"""## Umbra vs mitransient: samples/s and time to {tgt:.0%} relative error

Reproduce (from the repository root, after `cargo build --release`):

    .venv/bin/python python/bench/bench_vs_mitransient.py

Run {datetime.datetime.now().strftime('%Y-%m-%d %H:%M')}, {t_total / 60:.1f} min, on {platform.node() or 'this machine'}: {os.cpu_count()} cores ({cpu}),
{args.threads} threads for each renderer (`--threads {args.threads}`; mitransient `dr.set_thread_count({args.threads})`).
Load average (1/5/15 min) {load0} at the start, {load1} at the end (other jobs may share the machine;
renderers are interleaved so load hits both alike). Umbra binary built {bin_time}, HEAD {head}{' (uncommitted changes: ' + ' '.join(dirty) + ')' if dirty else ''};
mitransient {mt.mitr.__version__}, Mitsuba {mitsuba.__version__}, Dr.Jit {drjit.__version__}, variant llvm_ad_mono, LLVM 19.

Scenes `python/validation/scenes/{{T,arc}}.xml` (1 m wall, 16 x 16 scan points, 256 bins of 6 mm), both renderers
reading the same XML with the same `-D` overrides: `3b` = `max_depth=3, filter_bounces=2` (three-bounce only),
`mb` = `max_depth=6, filter_bounces=-1`. mitransient runs the XML's techniques (laser sampling + hidden-geometry
sampling, relay wall not included in HGS), its recommended NLOS setting. Umbra runs (i) the XML's techniques,
(ii) its MIS of BSDF + hidden-geometry sampling (`--bsdf-sampling true`), and for 3b (iii) `--model mc3`.

Method: error = relative L2 over all 16 x 16 x 256 bins (full time resolution) against a converged Umbra reference
(its own variance subtracted in quadrature), RMS over {SEEDS} seeds per spp (distinct seeds everywhere); ladders of powers
of two from {SPP_START} stop at the first spp below {args.stop_err:.1%}; a local fit log err = c + p log spp over the last {FIT_RUNGS} rungs
(p = -1/2 for independent samples; Umbra's scrambled-Sobol' samples converge faster, so p is fitted) gives spp*, the
spp for {tgt:.0%}. Each renderer then renders spp* {FINAL_REPS} times (interleaved A B C, C B A, A B C): "time at spp*" is the
median wall clock and "err at spp*" the RMS error of those renders. **Time to {tgt:.0%}** = time at spp* x
(err at spp* / {tgt})^(-1/p), a local correction for a fit that missed ("off fit": > 15 % away);
"ladder interp." is the log-log interpolation of the ladder's (time, error) points, for comparison.
mitransient times exclude scene loading and JIT compilation (each render's
kernel compile time, read from Dr.Jit's kernel history, is subtracted from its wall clock; a new spp compiles a new
kernel, ~0.4 s); Umbra times are the whole CLI process (XML parse, BVH build, render, .npy
write). samples/s = spp x 256 scan points / seconds, measured at one spp for all renderers (2 interleaved renders, median).
With "error at N spp" (N: the largest spp every renderer's ladder reached) it separates cost per sample from error per sample.
"""
    body = [head_txt, "### Summary", "", summary_table(cases, tgt)]
    body += [case_table(c, tgt) for c in cases]
    text = "\n".join(body)
    print("\n" + text)
    if not args.no_write:
        has_chart = chart(cases, tgt, CHART)
        text += ("\n![error vs time](python/bench/error_vs_time.png)\n" if has_chart else
                 "\n(No chart: matplotlib is not installed in .venv; `pip install matplotlib`.)\n")
        write_md(text)
        log(f"wrote {BENCH_MD}" + (f" and {CHART}" if has_chart else ""))


if __name__ == "__main__":
    main()
