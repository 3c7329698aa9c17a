"""Where a capture fit's excess over the photon floor lives (issue 48): the Poisson deviance
of `umbra.fit`'s fitted transient against the capture as fitted, split by time and by scan
point, so the next model term is chosen from the residual rather than guessed.

    .venv/bin/python python/studies/residual_anatomy.py [--captures exit_sign,...]
        [--out out/residual_anatomy] [--refit]

Per capture: `umbra.fit(scenes/lct.toml, data_X.mat)` with no options (the documented
defaults; skipped when OUT/X/fit.npz exists and --refit is not given), then

- the deviance per bin against time (summed over scan points, as a fraction of the bins'
  count, where a perfect model gives ~1 a bin): `time.png`, and the share of the excess
  deviance (deviance − bins) in the hidden signal's window (bins whose fitted hidden part
  is above 5 % of its peak) against the background-only bins;
- the deviance per scan point over the scan (`points.png`);
- the mean signed residual M − μ against time over all points, against μ's hidden part
  (a systematic shape error shows as structure in time; photon noise averages out);
- `summary.json` with these numbers.

The deviance uses q = 4 counts per value (the 8,2 binning averages 2 x 2 points: Poisson
sums of 4 points scaled by 1/4), as the fit's `deviance_per_bin` does.
"""
from __future__ import annotations

import argparse
import json
import os

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
DATA = os.path.join(ROOT, "..", "shared", "data", "lct")
CAPTURES = ("diffuse_s", "s_u", "exit_sign", "outdoor_s", "resolution_chart_40cm",
            "resolution_chart_65cm", "dot_chart_40cm", "dot_chart_65cm")
Q = 4.0


def fit(capture: str, d: str, refit: bool) -> dict:
    path = os.path.join(d, "fit.npz")
    if os.path.exists(path) and not refit:
        z = np.load(path)
        return {k: z[k] for k in z.files}
    import umbra
    scene = umbra.load_scene(os.path.join(ROOT, "scenes", "lct.toml"))
    out = umbra.fit(scene, os.path.join(DATA, f"data_{capture}.mat"), output=os.path.join(d, "fit"))
    res = {"render": np.asarray(out["render"]), "measured": np.asarray(out["measured"]),
           "relative_l2": np.float64(out["relative_l2"]),
           "floor": np.float64(out["photon_noise_floor"]),
           "deviance": np.float64(out["final_loss"]), "seconds": np.float64(out["seconds"])}
    np.savez(path, **res)
    return res


def deviance(m: np.ndarray, mu: np.ndarray) -> np.ndarray:
    mu = np.maximum(mu, 1e-12)
    with np.errstate(divide="ignore", invalid="ignore"):
        log = np.where(m > 0, m * np.log(m / mu), 0.0)
    return 2.0 * Q * (mu - m + log)


def anatomy(capture: str, res: dict, d: str) -> dict:
    m = res["measured"].astype(np.float64)
    mu = res["render"].astype(np.float64)
    m = m.reshape(-1, m.shape[-1])
    mu = mu.reshape(-1, mu.shape[-1])
    # The fitted bins: where the fit's model is nonzero (bins before the cut are zero).
    live = (mu > 0).all(axis=0)
    first = int(np.argmax(live))
    m, mu = m[:, first:], mu[:, first:]
    dev = deviance(m, mu)
    per_t = dev.mean(axis=0)
    per_p = dev.mean(axis=1)
    # The model's smooth part: the per-point floor is what the last bins hold; the hidden
    # window is where the model, less its per-point minimum over time, is above 5 % of its
    # peak (the direct tail decays monotonically, so this picks the hidden bump and the
    # earliest bins of the tail).
    hidden = mu - mu.min(axis=1, keepdims=True)
    shape = hidden.sum(axis=0)
    window = shape > 0.05 * shape.max()
    resid_t = (m - mu).mean(axis=0)
    excess = dev - 1.0
    out = {
        "capture": capture,
        "relative_l2": float(res["relative_l2"]), "floor": float(res["floor"]),
        "deviance_per_bin": float(dev.mean()),
        "window_bins": int(window.sum()), "bins": int(window.size),
        "deviance_in_window": float(dev[:, window].mean()),
        "deviance_outside_window": float(dev[:, ~window].mean()) if (~window).any() else None,
        "excess_share_in_window": float(excess[:, window].sum() / max(excess.sum(), 1e-12)),
        "worst_points_share": float(np.sort(per_p - 1)[::-1][: len(per_p) // 10].sum()
                                    / max((per_p - 1).sum(), 1e-12)),
        "first_bin": first,
    }
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        fig, ax = plt.subplots(3, 1, figsize=(8, 9), sharex=True)
        t = np.arange(first, first + per_t.size)
        ax[0].plot(t, per_t, lw=0.8)
        ax[0].axhline(1.0, color="k", lw=0.5)
        ax[0].set_ylabel("deviance / bin (mean over points)")
        ax[0].set_title(f"{capture}: rel. L2 {out['relative_l2']:.3f} "
                        f"(floor {out['floor']:.3f}), deviance {out['deviance_per_bin']:.2f}")
        ax[1].plot(t, resid_t, lw=0.8, label="mean(M - mu)")
        ax[1].plot(t, 0.1 * shape / m.shape[0], lw=0.8, label="0.1 x mean hidden part of mu")
        ax[1].axhline(0.0, color="k", lw=0.5)
        ax[1].legend(fontsize=8)
        ax[2].plot(t, m.mean(axis=0), lw=0.8, label="measured mean")
        ax[2].plot(t, mu.mean(axis=0), lw=0.8, label="fitted mean")
        ax[2].set_yscale("log")
        ax[2].legend(fontsize=8)
        ax[2].set_xlabel("time bin (as fitted)")
        fig.tight_layout()
        fig.savefig(os.path.join(d, "time.png"), dpi=90)
        plt.close(fig)
        n = int(round(np.sqrt(per_p.size)))
        fig, ax = plt.subplots(1, 2, figsize=(9, 4))
        im = ax[0].imshow(per_p.reshape(n, n), cmap="magma")
        ax[0].set_title("deviance / bin per scan point")
        fig.colorbar(im, ax=ax[0])
        im = ax[1].imshow(dev[:, window].mean(axis=1).reshape(n, n), cmap="magma")
        ax[1].set_title("... in the hidden window")
        fig.colorbar(im, ax=ax[1])
        fig.tight_layout()
        fig.savefig(os.path.join(d, "points.png"), dpi=90)
        plt.close(fig)
    except ImportError:
        pass
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--captures", default=",".join(CAPTURES))
    ap.add_argument("--out", default=os.path.join(ROOT, "out", "residual_anatomy"))
    ap.add_argument("--refit", action="store_true")
    a = ap.parse_args()
    rows = []
    for c in a.captures.split(","):
        d = os.path.join(a.out, c)
        os.makedirs(d, exist_ok=True)
        row = anatomy(c, fit(c, d, a.refit), d)
        with open(os.path.join(d, "summary.json"), "w") as f:
            json.dump(row, f, indent=1)
        print(json.dumps(row))
        rows.append(row)


if __name__ == "__main__":
    main()
