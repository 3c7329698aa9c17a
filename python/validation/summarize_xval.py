"""Summarise python/validation/cache/xval_report.md (written by
python/tests/test_vs_mitransient.py) into docs/VALIDATION.md: for each case, the latest
run's total energies, their ratio and z-score, and the relative L2 difference against
the one expected from both estimators' variance, as a function of spp.

Usage: .venv/bin/python python/validation/summarize_xval.py
"""
from __future__ import annotations

import datetime
import re
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPORT = HERE / "cache" / "xval_report.md"
OUT = HERE.parents[1] / "docs" / "VALIDATION.md"


def parse(text: str) -> dict[str, dict]:
    cases: dict[str, dict] = {}
    for block in text.split("### ")[1:]:
        lines = block.strip().splitlines()
        case = lines[0].strip()
        m = re.search(r"mitransient ([\d.e+-]+) \+- ([\d.]+)%, umbra ([\d.e+-]+) \+- ([\d.]+)%; "
                      r"umbra/mitransient = ([\d.]+) \(z = ([+-][\d.]+)\)", lines[1])
        rows = [[c.strip() for c in l.strip("|").split("|")] for l in lines[4:] if l.startswith("| ")]
        cases[case] = dict(total=m.groups() if m else None, rows=rows)   # later runs win
    return cases


def main() -> None:
    cases = parse(REPORT.read_text())
    out = [
        "# Umbra against mitransient 1.3.1",
        "",
        f"Generated {datetime.date.today()} by `python/validation/summarize_xval.py` from the last run",
        "of `python/tests/test_vs_mitransient.py` (part of `./test.sh`). Scenes and variants are",
        "described in that file; each side renders 3 independent seeds (16 x 16 scan, 256 bins,",
        "box bins, mitransient `llvm_ad_mono`).",
        "",
        "## Total energy",
        "",
        "| case | mitransient | Umbra | Umbra / mitransient | z |",
        "|---|---|---|---|---|",
    ]
    for case, c in cases.items():
        if c["total"]:
            tm, sm, tu, su, r, z = c["total"]
            out.append(f"| {case} | {float(tm):.5e} ± {sm} % | {float(tu):.5e} ± {su} % | {r} | {z} |")
    out += [
        "",
        "## Relative L2 difference as a function of spp",
        "",
        "`measured` = ||mean_mt − mean_umbra|| / ||H|| over k renders per side; `expected` =",
        "sqrt(var_mt + var_umbra) / ||H|| from each estimator's variance; `mt`, `umbra` = each",
        "estimator's own relative L2 noise at that spp. Full time resolution; the suite fails a",
        "case if measured > 1.5 x expected.",
        "",
        "| case | k | spp mt | spp umbra | measured | expected | mt | umbra | measured / expected |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for case, c in cases.items():
        for row in c["rows"]:
            if row[0] == "full":
                out.append(f"| {case} | " + " | ".join(row[1:]) + " |")
    OUT.parent.mkdir(exist_ok=True)
    OUT.write_text("\n".join(out) + "\n")
    print(f"wrote {OUT} ({len(cases)} cases)")


if __name__ == "__main__":
    main()
