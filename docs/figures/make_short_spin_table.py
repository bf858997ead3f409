"""The table of ``ablation_short_spin.py``'s records of one set (docs/calibration.md
section 7, session 10): per family the mean over its catheters of each variant (EM mm, EM
deg at 20 / 40 / 60 deg), its ratio to the reference on the same catheters (ours when the
records have it, else ``rings``), and the family x bend cells within 25 % of it::

    python docs/figures/make_short_spin_table.py docs/figures/short_variants_dev_s10.json spin

A third argument ``true`` tables the true pose's errors instead of the EM tracker's
(session 12: ``python docs/figures/make_short_spin_table.py
docs/figures/short_map_dev_s12.json map true``).
"""

from __future__ import annotations

import json
import sys
from collections import defaultdict

import numpy as np

with open(sys.argv[1]) as fh:
    records = [r for r in json.load(fh)["records"] if r["set"] == sys.argv[2]]
off = 2 if len(sys.argv) > 3 and sys.argv[3] == "true" else 0  # true pose: columns 2, 3
by_family: dict[str, list[dict[str, list[float]]]] = defaultdict(list)
for r in records:
    by_family[r["family"]].append(r["rows"])
ref = "ours" if all("ours" in r["rows"] for r in records) else "rings"
variants = [v for v in records[0]["rows"] if v != ref and all(v in r["rows"] for r in records)]
within = {v: [0, 0] for v in variants}
cells = 0
print("| family | variant | 20 deg | 40 deg | 60 deg |")
print("|---|---|---|---|---|")
for fam, rows in sorted(by_family.items()):
    ours = np.mean([r[ref] for r in rows], axis=0)
    print(
        f"| `{fam}` ({len(rows)}) | {ref} | "
        + " | ".join(
            f"{ours[4 * i + off]:.2f} mm, {ours[4 * i + 1 + off]:.2f} deg" for i in range(3)
        )
        + " |"
    )
    cells += 3
    for v in variants:
        m = np.mean([r[v] for r in rows], axis=0)
        parts = []
        for i in range(3):
            a, b = 4 * i + off, 4 * i + 1 + off
            rp, rr = m[a] / ours[a], m[b] / ours[b]
            within[v][0] += int(rp <= 1.25)
            within[v][1] += int(rr <= 1.25)
            parts.append(f"{m[a]:.2f} mm ({rp:.2f}x), {m[b]:.2f} deg ({rr:.2f}x)")
        print(f"| | {v} | " + " | ".join(parts) + " |")
print()
for v, (p, r) in within.items():
    print(f"{v}: within 25 % of {ref} in {p} of {cells} cells in position, {r} in rotation")
