"""Independent ISO 230-2 evaluation (numpy) of a positioning CSV: prints the iso230_2 keys as
JSON. A second implementation for metrology's tests; it shares no code with the Rust one."""
import csv, json, sys
import numpy as np

rows = [r for r in csv.reader(l for l in open(sys.argv[1]) if not l.startswith("#"))]
head, body = rows[0], rows[1:]
col = {h: i for i, h in enumerate(head)}
data = {}
for r in body:
    if r[col["deviation_um"]] == "":
        continue
    key = (int(r[col["index"]]), r[col["direction"]])
    data.setdefault(key, []).append(float(r[col["deviation_um"]]))
idx = sorted({k[0] for k in data})
mu = {d: np.array([np.mean(data[(i, d)]) for i in idx]) for d in "+-"}
sd = {d: np.array([np.std(data[(i, d)], ddof=1) for i in idx]) for d in "+-"}
B_i = mu["+"] - mu["-"]
R_up, R_dn = 4 * sd["+"], 4 * sd["-"]
R_i = np.maximum.reduce([2 * sd["+"] + 2 * sd["-"] + np.abs(B_i), R_up, R_dn])
xbar = (mu["+"] + mu["-"]) / 2
both_mu = np.concatenate([mu["+"], mu["-"]])
hi = np.concatenate([mu["+"] + 2 * sd["+"], mu["-"] + 2 * sd["-"]])
lo = np.concatenate([mu["+"] - 2 * sd["+"], mu["-"] - 2 * sd["-"]])
out = {
    "B": float(np.max(np.abs(B_i))),
    "B_mean": float(np.mean(B_i)),
    "R_up": float(R_up.max()),
    "R_down": float(R_dn.max()),
    "R": float(R_i.max()),
    "E_up": float(np.ptp(mu["+"])),
    "E_down": float(np.ptp(mu["-"])),
    "E": float(np.ptp(both_mu)),
    "M": float(np.ptp(xbar)),
    "A_up": float(np.max(mu["+"] + 2 * sd["+"]) - np.min(mu["+"] - 2 * sd["+"])),
    "A_down": float(np.max(mu["-"] + 2 * sd["-"]) - np.min(mu["-"] - 2 * sd["-"])),
    "A": float(hi.max() - lo.min()),
}
print(json.dumps(out))
