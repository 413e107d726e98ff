#!/usr/bin/env python3
"""The largest input each analysis command handles within 1 GiB of memory (issue 27).

For every command, inputs of growing size are generated (well-formed, with noise, so the work
is real), the command runs on each under a 1 GiB address-space limit, and its peak RSS, time
and exit are printed. Sizes grow by a factor until the command refuses the input with its
limit (exit 1, the limit in the message), runs out of the 1 GiB (exit ≠ 0 without a limit
message: a finding), or the largest size asked for is reached.

Usage:  python3 tests/sweep/largest_inputs.py BINARY [--only NAME] [--max-seconds S]
"""

import argparse
import math
import random
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "examples"
LIMIT = 1 << 30


def positioning(n_readings):
    """A positioning CSV of about n readings: 21 targets, as many cycles as it takes."""
    targets = 21
    cycles = max(1, n_readings // (2 * targets))
    rng = random.Random(1)
    out = ["cycle,direction,index,target_mm,deviation_um,time_s"]
    t = 0
    for c in range(1, cycles + 1):
        for d, order in (("+", range(1, targets + 1)), ("-", range(targets, 0, -1))):
            for i in order:
                t += 5
                dev = 3 * math.sin(i / 3) + (1.5 if d == "-" else 0) + rng.gauss(0, 0.4)
                out.append(f"{c},{d},{i},{(i - 1) * 25},{dev:.4f},{t}")
    return "\n".join(out) + "\n", f"{2 * targets * cycles} readings"


def diagnosable(n_readings):
    """Targets and cycles alike (the diagnosis' cost grows with readings × (targets + cycles))."""
    side = max(5, int((n_readings / 2) ** 0.5))
    rng = random.Random(2)
    out = ["cycle,direction,index,target_mm,deviation_um,time_s"]
    t = 0
    for c in range(1, side + 1):
        for d, order in (("+", range(1, side + 1)), ("-", range(side, 0, -1))):
            for i in order:
                t += 5
                out.append(f"{c},{d},{i},{(i - 1) * 10},{2 * math.sin(i / 7) + rng.gauss(0, 0.3):.4f},{t}")
    return "\n".join(out) + "\n", f"{2 * side * side} readings ({side} targets × {side} cycles)"


def thermal(n_rows):
    rng = random.Random(3)
    sensors = 16
    head = ["time_s", "spindle_rpm"] + [f"ch{k}_um" for k in range(1, 6)] + [f"t{k}_c" for k in range(1, sensors + 1)]
    out = [",".join(head)]
    temp = [20.0] * sensors
    for r in range(n_rows):
        rpm = 0 if (r // 240) % 2 else 1000 * (1 + (r // 480) % 4)
        for k in range(sensors):
            temp[k] += ((20 + rpm / 500 * (k + 1) / sensors) - temp[k]) / (60 + 20 * k)
        d = [0.8 * (temp[k] - 20) + rng.gauss(0, 0.1) for k in range(5)]
        out.append(",".join([str(15 * r), str(rpm)] + [f"{v:.3f}" for v in d] + [f"{v:.3f}" for v in temp]))
    return "\n".join(out) + "\n", f"{n_rows} rows × 16 sensors × 5 channels"


def capball(n_rows):
    lines = (EXAMPLES / "models" / "capball_identification.csv").read_text().splitlines()
    head = [l for l in lines if l.startswith("#") or not l[:1].isdigit()][:1]
    body = [l for l in lines if l[:1].isdigit()]
    out = head + [body[i % len(body)] for i in range(n_rows)]
    return "\n".join(out) + "\n", f"{n_rows} rows"


def psd(n_runs):
    lines = (EXAMPLES / "models" / "psd_readings.csv").read_text().splitlines()
    head, body = lines[0], [l for l in lines[1:] if l and l[0].isdigit()]
    runs = sorted({l.split(",")[0] for l in body})
    per = [l for l in body if l.split(",")[0] == runs[0]]
    out = [head]
    for r in range(n_runs):
        out += [f"{r}," + l.split(",", 1)[1] for l in per]
    return "\n".join(out) + "\n", f"{n_runs} runs ({n_runs * len(per)} rows)"


def components(n_points):
    out = ["error,position_mm,value"]
    for name in ["EXX", "EYX", "EZX", "EAX", "EBX", "ECX"]:
        for k in range(n_points):
            out.append(f"{name},{k * 400 / max(1, n_points - 1):.6f},{math.sin(k / 5):.4f}")
    return "\n".join(out) + "\n", f"{n_points} points per table"


def budget(trials):
    text = (EXAMPLES / "budgets" / "jcgm101_9_2_2_additive_normal.toml").read_text()
    lines = [l for l in text.splitlines() if not l.strip().startswith("trials")]
    out, done = [], False
    for l in lines:
        out.append(l)
        if l.strip() == "[settings]" and not done:
            out.append(f"trials = {trials}")
            done = True
    if not done:
        out += ["[settings]", f"trials = {trials}"]
    return "\n".join(out) + "\n", f"{trials} trials"


# name → (generator, sizes, command with {i} and {o}, suffix)
JOBS = {
    "analyze positioning": (positioning, [10_000, 100_000, 200_000], "analyze positioning {i}", ".csv"),
    "report": (positioning, [10_000, 100_000], "report {i} -o {o}/r.html", ".csv"),
    "compensate positioning": (positioning, [10_000, 100_000], "compensate positioning {i} --dialect linuxcnc --bidirectional -o {o}", ".csv"),
    "diagnose": (diagnosable, [2_000, 10_000, 30_000, 60_000], "diagnose {i}", ".csv"),
    "thermal fit": (thermal, [2_000, 20_000, 100_000], "thermal fit {i} -o {o}/m.json", ".csv"),
    "thermal diagnose": (thermal, [2_000, 20_000, 100_000], "thermal diagnose {i}", ".csv"),
    "analyze thermal": (thermal, [20_000, 200_000, 1_000_000], "analyze thermal {i} --probes ch1,ch2,ch3,ch4,ch5 --probe-spacing-mm 100", ".csv"),
    "identify capball": (capball, [1_000, 10_000, 100_000, 1_000_000], "identify capball {i}", ".csv"),
    "identify psd": (psd, [10, 100, 1_000, 10_000], "identify psd {i} --reference 0", ".csv"),
    "volumetric": (components, [100, 1_000, 10_000], "volumetric --errors {i} --machine " + str(EXAMPLES / "models" / "machine_3axis.toml") + " --grid 0:400:41,0:300:31,0:200:21 --out {o}/t.csv --siemens {o}/c.ini", ".csv"),
    "uncertainty": (budget, [100_000, 2_000_000, 20_000_000, 20_000_001], "uncertainty {i}", ".toml"),
}


def limit():
    resource.setrlimit(resource.RLIMIT_AS, (LIMIT, LIMIT))


def measured(binary, args, max_s):
    """Exit, peak RSS (MiB), seconds and stderr of one run, in a child of its own."""
    code = (
        "import resource,subprocess,sys,time\n"
        "def lim(): resource.setrlimit(resource.RLIMIT_AS,(%d,%d))\n"
        "t=time.monotonic()\n"
        "try:\n"
        "  p=subprocess.run(sys.argv[1:],stdout=subprocess.DEVNULL,stderr=subprocess.PIPE,stdin=subprocess.DEVNULL,preexec_fn=lim,timeout=%f)\n"
        "  c=p.returncode; e=p.stderr.decode(errors='replace')\n"
        "except subprocess.TimeoutExpired:\n"
        "  c=None; e='over the time given'\n"
        "r=resource.getrusage(resource.RUSAGE_CHILDREN)\n"
        "print(c, r.ru_maxrss, time.monotonic()-t)\n"
        "sys.stdout.write(e)\n" % (LIMIT, LIMIT, max_s)
    )
    p = subprocess.run([sys.executable, "-c", code, binary] + args, capture_output=True, text=True)
    first, _, err = p.stdout.partition("\n")
    c, rss_kb, secs = first.split()
    return (None if c == "None" else int(c)), int(rss_kb) / 1024, float(secs), err


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("binary")
    ap.add_argument("--only", default=None)
    ap.add_argument("--max-seconds", type=float, default=600)
    a = ap.parse_args()
    for name, (gen, sizes, cmd, suffix) in JOBS.items():
        if a.only and a.only != name:
            continue
        for n in sizes:
            with tempfile.TemporaryDirectory() as t:
                text, what = gen(n)
                inp = Path(t) / ("input" + suffix)
                inp.write_text(text)
                out = Path(t) / "out"
                out.mkdir()
                args = [x.replace("{i}", str(inp)).replace("{o}", str(out)) for x in cmd.split(" ")]
                code, rss, secs, err = measured(a.binary, args, a.max_seconds)
                size = inp.stat().st_size / 2**20
                msg = err.strip().splitlines()[-1][:160] if code not in (0, None) and err.strip() else ""
                print(f"{name:24} {what:42} {size:8.1f} MiB  exit {code}  peak RSS {rss:7.0f} MiB  {secs:7.1f} s  {msg}", flush=True)
                if code != 0:
                    break


if __name__ == "__main__":
    main()
