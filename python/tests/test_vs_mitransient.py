"""Cross-validation of Umbra's CLI against mitransient 1.3.1 (transient_nlos_path).

Scenes: python/validation/scenes/{T,arc,near}.xml (planar letter at ~1 m, bent sheet at ~1 m,
plate at 0.35 m), each rendered as a `single` and a `confocal` capture (16x16 scan, 256 bins),
in these variants:

  3b-hgs   three-bounce only, hidden-geometry sampling   (Umbra --model mc3)
  3b-bsdf  three-bounce only, BSDF sampling              (Umbra --model path, BSDF only)
  3b-mis   three-bounce only, mitransient HGS            (Umbra --model path, its MIS of
           BSDF and hidden-geometry sampling)
  3b-tri3  three-bounce only, mitransient HGS            (Umbra --model tri3, deterministic)
  mb-hgs   up to 6 bounces, HGS without the relay wall   (Umbra --model path): path space
           WITHOUT relay-wall vertices between x_s and x_l (mitransient's HGS never samples
           the wall)
  mb-hgs-wall  up to 6 bounces, HGS including the wall  (Umbra --model path): all paths
  mb-bsdf  up to 6 bounces, BSDF sampling                (Umbra --model path): all paths,
           including relay-wall interreflections
  mb-mis   up to 6 bounces, mitransient BSDF sampling    (Umbra --model path, MIS): all paths

For T and arc the relay-wall inter-reflections fall outside the time window (T: mb == 3b in
mitransient); `near` puts them inside: there mb-bsdf = mb-hgs-wall = mb-hgs + ~3 %.

Both renderers read the same variant XML (cache/variants/, <default> values filled in).
Umbra CLI: `umbra render SCENE.xml -o OUT.npy --spp N --seed S --model mc3|path`, writing
float32 (sy, sx, T). mitransient renders are cached in python/validation/cache/ keyed by a
hash of the scene, meshes, spp, seed and versions.

Statistics (K independent seeds per renderer):
- total energy: |sum(U) - sum(M)| <= 1% of sum(M) + 3 sigma, sigma from the per-scan-point
  variances across seeds (scan points are sampled independently, so they add);
- relative L2: ||mean_k(M) - mean_k(U)|| / ||H|| against its expectation under "no bias",
  sqrt(sum_bins(var_M + var_U) / k) / ||H|| (per-bin variances of one render, estimated
  across seeds), for k = 1..K (effective spp = k * spp), at full resolution and with time
  bins summed in groups of 8 (more sensitive to bias); must be <= 1.5x the expectation.

Env: UMBRA_BIN (see conftest), UMBRA_XVAL_SPP_SCALE (multiplies Umbra's spp, default 1),
UMBRA_XVAL_CASES (comma-separated substrings selecting cases, e.g. "T-single,3b").
A table per case is printed (pytest -s) and appended to cache/xval_report.md.
"""
from __future__ import annotations

import hashlib
import os
import re
import shutil
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

from conftest import SELF_CHECK, VALIDATION, require_umbra

SCENES_DIR = VALIDATION / "scenes"
K = 3                     # independent renders per renderer
L2_FACTOR = 1.5           # measured rel. L2 must be <= L2_FACTOR x expected
TOTAL_TOL = 0.01          # 1 % on the total energy, plus 3 sigma of MC error
COARSE = 8                # time bins merged for the coarse L2

MIS = ["--hidden-geometry-sampling", "true", "--bsdf-sampling", "true"]
VARIANTS = {
    #           XML <default> overrides                                              model   mt spp umbra spp  umbra extra args
    "3b-hgs": (dict(max_depth=3, filter_bounces=2, hgs="true", hgs_wall="false"), "mc3", 2048, 2048, []),
    "3b-bsdf": (dict(max_depth=3, filter_bounces=2, hgs="false", hgs_wall="false"), "path", 16384, 16384, []),
    "3b-mis": (dict(max_depth=3, filter_bounces=2, hgs="true", hgs_wall="false"), "path", 2048, 2048, MIS),
    # Umbra's deterministic per-triangle model (no noise: its "variance" is 0).
    "3b-tri3": (dict(max_depth=3, filter_bounces=2, hgs="true", hgs_wall="false"), "tri3", 2048, 1, []),
    "mb-hgs": (dict(max_depth=6, filter_bounces=-1, hgs="true", hgs_wall="false"), "path", 2048, 2048, []),
    "mb-hgs-wall": (dict(max_depth=6, filter_bounces=-1, hgs="true", hgs_wall="true"), "path", 4096, 2048, []),
    "mb-bsdf": (dict(max_depth=6, filter_bounces=-1, hgs="false", hgs_wall="false"), "path", 16384, 4096, []),
    # Umbra's default estimator (MIS of BSDF and hidden-geometry sampling) against
    # mitransient's BSDF sampling, which reaches every path.
    "mb-mis": (dict(max_depth=6, filter_bounces=-1, hgs="false", hgs_wall="false"), "path", 16384, 2048, MIS),
}
SCENE_VARIANTS = {
    "T": ["3b-hgs", "3b-bsdf", "3b-mis", "3b-tri3", "mb-hgs", "mb-bsdf", "mb-mis"],
    "arc": ["3b-hgs", "3b-bsdf", "3b-mis", "3b-tri3", "mb-hgs", "mb-bsdf", "mb-mis"],
    "near": ["3b-hgs", "mb-hgs", "mb-hgs-wall", "mb-bsdf", "mb-mis"],
}
CAPTURES = ["single", "confocal"]
CASES = [(s, c, v) for s, vs in SCENE_VARIANTS.items() for c in CAPTURES for v in vs]


def _selected(case_id: str) -> bool:
    sel = os.environ.get("UMBRA_XVAL_CASES")
    return not sel or any(tok and tok in case_id for tok in sel.split(","))


# ----------------------------------------------------------------------------- scene files

def write_variant(scene: str, capture: str, variant: str, dest: Path) -> Path:
    """Copy scenes/<scene>.xml with its <default> values replaced (and its meshes) to dest/."""
    params = {**VARIANTS[variant][0], "capture_type": capture}
    text = (SCENES_DIR / f"{scene}.xml").read_text()
    for k, v in params.items():
        text, n = re.subn(rf'(<default\s+name="{k}"\s+value=")[^"]*(")', rf"\g<1>{v}\g<2>", text)
        assert n == 1, f"<default name={k!r}> not found exactly once in {scene}.xml"
    dest.mkdir(parents=True, exist_ok=True)
    for fn in re.findall(r'name="filename"\s+value="([^"]+)"', text):
        shutil.copyfile(SCENES_DIR / fn, dest / fn)
    out = dest / f"{scene}-{capture}-{variant}.xml"
    out.write_text(text)
    return out


def scene_hash(xml: Path) -> str:
    h = hashlib.sha256(xml.read_bytes())
    for fn in sorted(re.findall(r'name="filename"\s+value="([^"]+)"', xml.read_text())):
        h.update((xml.parent / fn).read_bytes())
    return h.hexdigest()


# ----------------------------------------------------------------------------- renderers

def mt_render(mt, xml: Path, spp: int, seed: int, cache_dir: Path) -> np.ndarray:
    """mitransient render (float32 (sy, sx, T)), cached on disk."""
    mi, mitr = mt
    import mtutil

    key = hashlib.sha256(
        f"{scene_hash(xml)}|{spp}|{seed}|{mi.__version__}|{mitr.__version__}|llvm_ad_mono".encode()
    ).hexdigest()[:16]
    path = cache_dir / f"mt-{xml.stem}-spp{spp}-seed{seed}-{key}.npy"
    if path.exists():
        return np.load(path)
    H = mtutil.render_scene(mtutil.load_xml(xml), spp=spp, seed=seed)
    np.save(path, H.astype(np.float32))
    return H


def umbra_render(umbra_bin: str, xml: Path, spp: int, seed: int, model: str, out_dir: Path,
                 extra: list[str] | None = None) -> np.ndarray:
    out = out_dir / f"umbra-{xml.stem}-spp{spp}-seed{seed}.npy"
    cmd = [umbra_bin, "render", str(xml), "-o", str(out), "--spp", str(spp), "--seed", str(seed),
           "--model", model, "--no-preview", "-q"] + list(extra or [])
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=900)
    if r.returncode != 0:
        pytest.fail(f"umbra failed (exit {r.returncode}): {' '.join(cmd)}\n"
                    f"stdout: {r.stdout[-2000:]}\nstderr: {r.stderr[-4000:]}", pytrace=False)
    if not out.exists():
        pytest.fail(f"umbra exited 0 but wrote no {out}: {' '.join(cmd)}", pytrace=False)
    return np.load(out)


# ----------------------------------------------------------------------------- statistics

def compare(M: np.ndarray, U: np.ndarray, spp_m: int, spp_u: int) -> dict:
    """M, U: (K, sy, sx, T) independent renders of mitransient and Umbra."""
    M = M.astype(np.float64)
    U = U.astype(np.float64)
    k_max = min(len(M), len(U))
    H = M.mean(0)
    res = {"rows": []}
    for label, f in (("full", lambda a: a),
                     ("coarse", lambda a: a.reshape(*a.shape[:-1], a.shape[-1] // COARSE, COARSE).sum(-1))):
        Mf, Uf = f(M), f(U)
        Hf = f(H)
        nH = np.linalg.norm(Hf)
        vm = Mf.var(0, ddof=1).sum()
        vu = Uf.var(0, ddof=1).sum()
        for k in range(1, k_max + 1):
            meas = np.linalg.norm(Mf[:k].mean(0) - Uf[:k].mean(0)) / nH
            exp = np.sqrt((vm + vu) / k) / nH
            res["rows"].append((label, k, k * spp_m, k * spp_u, meas, exp,
                                np.sqrt(vm / k) / nH, np.sqrt(vu / k) / nH))
    Pm, Pu = M.sum(-1), U.sum(-1)                    # per-scan-point totals (K, sy, sx)
    tm, tu = Pm.mean(0).sum(), Pu.mean(0).sum()
    sm = np.sqrt(Pm.var(0, ddof=1).sum() / len(Pm))  # stderr of the K-render mean total
    su = np.sqrt(Pu.var(0, ddof=1).sum() / len(Pu))
    res.update(tot_m=tm, tot_u=tu, se_m=sm, se_u=su)
    return res


def report(case_id: str, res: dict) -> str:
    tm, tu, sm, su = res["tot_m"], res["tot_u"], res["se_m"], res["se_u"]
    sd = np.hypot(sm, su)
    lines = [f"### {case_id}",
             f"total: mitransient {tm:.6e} +- {sm / tm:.2%}, umbra {tu:.6e} +- {su / max(tu, 1e-30):.2%}; "
             f"umbra/mitransient = {tu / tm:.5f} (z = {(tu - tm) / sd:+.2f})",
             "| L2 | k | spp mt | spp umbra | measured rel L2 | expected | mt part | umbra part | ratio |",
             "|---|---|---|---|---|---|---|---|---|"]
    for label, k, sm_, su_, meas, exp, pm, pu in res["rows"]:
        lines.append(f"| {label} | {k} | {sm_} | {su_} | {meas:.4f} | {exp:.4f} | {pm:.4f} | {pu:.4f} "
                     f"| {meas / exp:.3f} |")
    return "\n".join(lines) + "\n"


# ----------------------------------------------------------------------------- tests

def test_mitransient_conventions(mt, cache_dir):
    """The layout and scan geometry that Umbra reproduces (see notes/mitransient.md)."""
    import mtutil

    mi, _ = mt
    xml = write_variant("T", "single", "3b-hgs", cache_dir / "variants")
    scene = mtutil.load_xml(xml)
    H = mtutil.render_scene(scene, spp=1, seed=0)
    assert H.shape == (16, 16, 256) and H.dtype == np.float32
    integ = scene.integrator()
    st = np.array(integ.sensor_targets)
    st = st.T if st.shape[0] == 3 else st
    ix, iy = np.meshgrid(np.arange(16), np.arange(16))
    exp = np.stack([0.5 * ((2 * ix + 1) / 16 - 1), 0.5 * ((2 * iy + 1) / 16 - 1), 0 * ix], -1)
    assert np.allclose(st, exp.reshape(-1, 3), atol=1e-6)   # H[iy, ix] <-> (u_ix, v_iy)
    lt = np.array(integ.laser_targets).ravel()
    assert np.allclose(lt, [0.1, 0.1, 0.0], atol=1e-6)     # projector axis hits the wall here


@pytest.mark.parametrize("scene,capture,variant", CASES, ids=[f"{s}-{c}-{v}" for s, c, v in CASES])
def test_vs_mitransient(scene, capture, variant, mt, umbra_bin, cache_dir, tmp_path):
    case_id = f"{scene}-{capture}-{variant}"
    if not _selected(case_id):
        pytest.skip("deselected by UMBRA_XVAL_CASES")
    require_umbra(umbra_bin)
    params, model, spp_m, spp_u, extra = VARIANTS[variant]
    spp_u = max(1, int(round(spp_u * float(os.environ.get("UMBRA_XVAL_SPP_SCALE", "1")))))
    xml = write_variant(scene, capture, variant, cache_dir / "variants")

    t0 = time.time()
    M = np.stack([mt_render(mt, xml, spp_m, s, cache_dir) for s in range(K)])
    t1 = time.time()
    if umbra_bin == SELF_CHECK:      # calibration: mitransient with other seeds plays Umbra
        spp_u = spp_m
        U = np.stack([mt_render(mt, xml, spp_m, 1000 + s, cache_dir) for s in range(K)])
    else:
        U = np.stack([umbra_render(umbra_bin, xml, spp_u, s, model, tmp_path, extra) for s in range(K)])
    t2 = time.time()

    assert U.shape == M.shape, f"Umbra output shape {U.shape[1:]} != mitransient {M.shape[1:]} (sy, sx, T)"
    assert U.dtype == np.float32, f"Umbra output dtype {U.dtype}, expected float32"
    assert np.isfinite(U).all(), "Umbra output has NaN/inf"
    assert (U >= 0).all(), f"Umbra output has negative values (min {U.min()})"

    res = compare(M, U, spp_m, spp_u)
    text = report(case_id, res) + f"(mitransient {t1 - t0:.1f} s incl. cache, umbra {t2 - t1:.1f} s)\n"
    print("\n" + text)
    with open(cache_dir / "xval_report.md", "a") as f:
        f.write(text + "\n")

    tm, tu = res["tot_m"], res["tot_u"]
    sd = np.hypot(res["se_m"], res["se_u"])
    assert abs(tu - tm) <= TOTAL_TOL * tm + 3 * sd, (
        f"total energy: umbra/mitransient = {tu / tm:.4f}, |diff| {abs(tu - tm) / tm:.2%} > "
        f"{TOTAL_TOL:.0%} + 3 sigma ({3 * sd / tm:.2%})")
    bad = [r for r in res["rows"] if r[4] > L2_FACTOR * r[5]]
    assert not bad, "relative L2 above {}x its expectation: {}".format(
        L2_FACTOR, "; ".join(f"{r[0]} k={r[1]}: {r[4]:.4f} vs {r[5]:.4f}" for r in bad))
