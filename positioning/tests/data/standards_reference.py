"""Independent evaluation of a positioning CSV by the standards of docs/methods.md
"Positioning standards", written from the formulas in that section with the Python standard
library only (no code shared with metrolog's Rust). Prints {designation: {symbol: value}}."""
import csv, json, statistics, sys

rows = [r for r in csv.reader(l for l in open(sys.argv[1]) if not l.startswith("#"))]
head, body = rows[0], rows[1:]
c = {h: i for i, h in enumerate(head)}
obs = {}
for r in body:
    if r[c["deviation_um"]].strip() == "":
        continue
    obs.setdefault((int(r[c["index"]]), r[c["direction"]]), []).append(float(r[c["deviation_um"]]))
targets = sorted({i for i, _ in obs})
mean = {k: statistics.mean(v) for k, v in obs.items()}
sd = {k: statistics.stdev(v) for k, v in obs.items() if len(v) > 1}


def iso(k):
    """ISO 230-2 parameters with bands of +-k s."""
    up = [(mean[(i, "+")], sd[(i, "+")]) for i in targets]
    dn = [(mean[(i, "-")], sd[(i, "-")]) for i in targets]
    out = {}
    out["A↑"] = max(m + k * s for m, s in up) - min(m - k * s for m, s in up)
    out["A↓"] = max(m + k * s for m, s in dn) - min(m - k * s for m, s in dn)
    out["A"] = max(m + k * s for m, s in up + dn) - min(m - k * s for m, s in up + dn)
    out["R↑"] = max(2 * k * s for _, s in up)
    out["R↓"] = max(2 * k * s for _, s in dn)
    rev = [u[0] - d[0] for u, d in zip(up, dn)]
    out["R"] = max(max(k * u[1] + k * d[1] + abs(b), 2 * k * u[1], 2 * k * d[1])
                   for u, d, b in zip(up, dn, rev))
    out["B"] = max(abs(b) for b in rev)
    out["B̄"] = sum(rev) / len(rev)
    out["E↑"] = max(m for m, _ in up) - min(m for m, _ in up)
    out["E↓"] = max(m for m, _ in dn) - min(m for m, _ in dn)
    out["E"] = max(m for m, _ in up + dn) - min(m for m, _ in up + dn)
    xbar = [(u[0] + d[0]) / 2 for u, d in zip(up, dn)]
    out["M"] = max(xbar) - min(xbar)
    return out


def vdi():
    xbar, U, Ps = [], [], []
    for i in targets:
        xbar.append((mean[(i, "+")] + mean[(i, "-")]) / 2)
        U.append(abs(mean[(i, "+")] - mean[(i, "-")]))
        Ps.append(6 * (sd[(i, "+")] + sd[(i, "-")]) / 2)
    hi = max(x + (u + p) / 2 for x, u, p in zip(xbar, U, Ps))
    lo = min(x - (u + p) / 2 for x, u, p in zip(xbar, U, Ps))
    return {"P": hi - lo, "Pa": max(xbar) - min(xbar), "Ps max": max(Ps),
            "P̄s": sum(Ps) / len(Ps), "U max": max(U), "Ū": sum(U) / len(U)}


print(json.dumps({
    "ISO 230-2:2014": iso(2), "ISO 230-2:2006": iso(2), "ISO 230-2:1997": iso(2),
    "ISO 230-2:1988": iso(3), "VDI/DGQ 3441:1977": vdi(), "ASME B5.54-2005": iso(2),
    "JIS B 6192:1999": iso(2), "GB/T 17421.2-2016": iso(2), "GB/T 17421.2-2000": iso(2),
}, ensure_ascii=False))
