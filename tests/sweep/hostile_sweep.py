#!/usr/bin/env python3
"""A hostile sweep of every analysis command (issue 27), written apart from the corpus test.

Mutates the project's example datasets, the real runs, the budgets and the test logs (numbers
replaced by huge, tiny, non-finite or non-numeric ones; rows dropped, repeated and reordered;
columns duplicated; files cut, bit-flipped, padded with NULs, CRLF, BOM; comment lines that
try to inject NC lines or paths), crosses them with hostile command-line values, runs the
binary on each under a 1 GiB address-space limit and a deadline, and reports every run that:

- ends by a signal (panic → 101, abort → 134, SIGSEGV …) or with an exit code outside the
  README's table (0, 1, 2, 74, 78);
- hangs (no end within the deadline);
- prints "panicked" or a Rust backtrace;
- leaves a NaN or an infinity in its stdout or in a text file it wrote;
- prints a control character (an escape sequence from an input) on stdout or stderr;
- writes anything outside its output directory, or leaves files there after a failure.

Usage:  python3 tests/sweep/hostile_sweep.py BINARY [--seed N] [--runs N] [--jobs N]
A summary line per check and the first failures (command, input kept in --keep DIR) are
printed; the exit status is 1 when a run broke a rule.
"""

import argparse
import concurrent.futures as cf
import os
import random
import re
import resource
import shutil
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "examples"
ALLOWED_EXIT = {0, 1, 2, 74, 78}
MEMORY = 1 << 30
DEADLINE_S = 120
NONFINITE = re.compile(r"(?<![A-Za-z_])(?:[-+]?inf(?:inity)?|nan)(?![A-Za-z_])", re.I)
BAD_NUMBERS = [
    "1e308", "-1e308", "1e155", "-1e155", "nan", "NaN", "inf", "-inf", "+inf", "1e-320",
    "0", "-0", "4294967296", "18446744073709551616", "-1", "", "abc", "0x10", "1_000",
    "1e", ".", "--1", "9" * 400, "1,5", "١٢", "1e-9", "1e9", "1\x1b[2J",
]


# A control character a terminal acts on (all but tab, newline and carriage return).
CONTROL = re.compile(r"[\x00-\x08\x0b\x0c\x0e-\x1f\x7f-\x9f]")


def seeds():
    """(kind, name, bytes) of every seed input."""
    out = []
    for p in sorted(EXAMPLES.rglob("*")):
        if p.suffix in (".csv", ".toml", ".json"):
            out.append((kind_of(p), p.name, p.read_bytes()))
    for d in [ROOT / "positioning" / "tests" / "data", ROOT / "daemon" / "tests" / "hostile",
              ROOT.parent / "shared" / "real" / "thermal"]:
        if d.is_dir():
            for p in sorted(d.rglob("*.csv")):
                out.append((kind_of(p), p.name, p.read_bytes()[:400_000]))
    for p in sorted((ROOT / "log" / "tests" / "data").glob("*.mcap")):
        out.append(("log", p.name, p.read_bytes()))
    return out


def kind_of(p: Path) -> str:
    text = p.read_text(errors="replace")[:4000]
    head = "\n".join(l for l in text.splitlines() if not l.startswith("#"))[:400]
    if p.suffix == ".toml":
        if "[machine]" in text or "chain" in text:
            return "machine"
        return "budget"
    if p.suffix == ".json":
        return "json"
    if "deviation_um" in head:
        return "positioning"
    if "e_um" in head or "c_deg" in head or "ex_um" in head:
        return "capball"
    if "_c," in head or head.rstrip().endswith("_c"):
        return "thermal"
    if "error,position_mm" in head:
        return "components"
    if "x_um" in head or "psd" in p.name:
        return "psd"
    return "csv"


# What each kind of input is given to: command lines with {i} the input, {o} the output dir.
COMMANDS = {
    "positioning": [
        "analyze positioning {i}", "analyze positioning {i} --json",
        "report {i} -o {o}/r.html", "diagnose {i}", "diagnose {i} --json",
        "diagnose {i} --write-model {o}/m.toml",
        "compensate positioning {i} --dialect linuxcnc --bidirectional -o {o}",
        "compensate positioning {i} --dialect sinumerik -o {o}",
        "compensate positioning {i} --dialect fanuc -o {o}",
        "compensate positioning {i} --dialect heidenhain -o {o}",
        "compensate verify {i} {i}",
    ],
    "capball": ["identify capball {i}", "identify capball {i} --json", "diagnose --capball {i}"],
    "psd": ["identify psd {i} --reference 0", "identify psd {i} --reference 0 --json"],
    "thermal": [
        "thermal fit {i} -o {o}/m.json", "thermal diagnose {i}", "analyze thermal {i}",
        "analyze thermal {i} --json",
    ],
    "components": [
        "volumetric --errors {i} --machine {x}/models/machine_3axis.toml --grid 0:400:3,0:300:3,0:200:3 --out {o}/t.csv --siemens {o}/cec.ini",
    ],
    "budget": ["uncertainty {i}", "uncertainty {i} --json"],
    "log": [
        "info {i}", "replay {i}", "recover {i} -o {o}/fixed.mcap", "analyze positioning {i}",
        "identify capball {i}", "identify psd {i} --reference 0", "thermal fit {i} -o {o}/m.json",
        "compensate positioning {i} --dialect linuxcnc -o {o}",
    ],
    "csv": ["analyze positioning {i}", "identify capball {i}", "thermal diagnose {i}"],
    "machine": ["volumetric --errors {x}/models/component_errors.csv --machine {i} --grid 0:400:3,0:300:3,0:200:3 --out {o}/t.csv"],
    "json": [],
}

# Hostile option values crossed with a well-formed input.
OPTIONS = [
    ("positioning", "compensate positioning {i} --dialect linuxcnc --spacing {v} -o {o}"),
    ("positioning", "compensate positioning {i} --dialect linuxcnc --reference-point {v} -o {o}"),
    ("positioning", "compensate positioning {i} --dialect fanuc --axis-number {v} -o {o}"),
    ("positioning", "compensate positioning {i} --dialect fanuc --point-limit {v} -o {o}"),
    ("positioning", "compensate positioning {i} --dialect sinumerik --axis-name {n} -o {o}"),
    ("positioning", "compensate positioning {i} --dialect heidenhain --axis-name {n} -o {o}"),
    ("positioning", "analyze positioning {i} --assume device_um_per_m={v}"),
    ("positioning", "analyze positioning {i} --tolerance E={v}"),
    ("positioning", "analyze positioning {i} --units {v},um"),
    ("positioning", "diagnose {i} --check-seeds {v}"),
    ("positioning", "report {i} --assume misalignment_mrad={v} -o {o}/r.html"),
    ("capball", "identify capball {i} --uncertainty mc --trials {v}"),
    ("capball", "identify capball {i} --uncertainty mc --ndig {v}"),
    ("capball", "identify capball {i} --sensor-u-um {v}"),
    ("psd", "identify psd {i} --reference {v}"),
    ("psd", "identify psd {i} --reference 0 --sigma-um {v}"),
    ("psd", "identify psd {i} --reference 0 --layout 0,{v},0,167,0,350"),
    ("budget", "uncertainty {i} --trials {v}"),
    ("budget", "uncertainty {i} --ndig {v}"),
    ("thermal", "analyze thermal {i} --probes ch1,ch2,ch3,ch4,ch5 --probe-spacing-mm {v}"),
    ("thermal", "thermal fit {i} --blocks {v} -o {o}/m.json"),
    ("components", "volumetric --errors {i} --machine {x}/models/machine_3axis.toml --grid 0:{v}:3,0:300:3,0:200:3 --out {o}/t.csv"),
    ("components", "volumetric --errors {i} --machine {x}/models/machine_3axis.toml --grid 0:400:3,0:300:3,0:200:3 --siemens {o}/c.ini --axis-names {n},AX2,AX3"),
    ("positioning", "analyze positioning {i} --reference-cycle {v}"),
    ("positioning", "analyze positioning {i} --plot-target {v} --plot {o}/p.svg"),
    ("capball", "identify capball {i} --warmup-runs {v}"),
    (None, "identify trajectory --poses {v} --out {o}/t.csv"),
    (None, "identify trajectory --c-turns {v} --out {o}/t.csv"),
    (None, "identify trajectory --a-end-deg {v} --out {o}/t.csv"),
    (None, "plan positioning --from 0 --to {v} -o {o}"),
    (None, "plan positioning --from 0 --to 500 --cycles {v} -o {o}"),
    (None, "plan positioning --from 0 --to 500 --dwell {v} -o {o}"),
    (None, "plan positioning --from 0 --to 500 --targets {v} -o {o}"),
    (None, "plan positioning --from 0 --to 500 --feed {v} --dialect fanuc -o {o}"),
]
NAMES = ["../../escaped", "X]=0 ;", "X\nM30", "X\r\nM30", "", "A" * 300, "X;(", "/tmp/x", "Ä"]


def mutate(data: bytes, rng: random.Random) -> bytes:
    """One hostile change of a seed."""
    if data[:4] == b"\x89MCA":
        return mutate_bytes(data, rng)
    text = data.decode("utf-8", errors="replace")
    lines = text.split("\n")
    op = rng.randrange(12)
    if op <= 3:  # a number replaced
        cells = [(i, m) for i, l in enumerate(lines) if not l.startswith("#")
                 for m in re.finditer(r"-?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?", l)]
        for _ in range(1 + (op == 3) * rng.randrange(1, 20)):
            if not cells:
                break
            i, m = rng.choice(cells)
            l = lines[i]
            if m.end() <= len(l) and l[m.start():m.end()] == m.group(0):
                lines[i] = l[:m.start()] + rng.choice(BAD_NUMBERS) + l[m.end():]
    elif op == 4 and len(lines) > 2:  # rows dropped
        for _ in range(rng.randrange(1, max(2, len(lines) // 3))):
            if len(lines) > 2:
                del lines[rng.randrange(1, len(lines))]
    elif op == 5 and len(lines) > 2:  # rows repeated / shuffled
        body = lines[1:]
        if rng.random() < 0.5:
            body += rng.choices(body, k=rng.randrange(1, len(body) + 1))
        rng.shuffle(body)
        lines = lines[:1] + body
    elif op == 6:  # a header column duplicated or renamed
        hi = next((i for i, l in enumerate(lines) if l and not l.startswith("#")), 0)
        cols = lines[hi].split(",")
        j = rng.randrange(len(cols))
        if rng.random() < 0.5:
            cols[rng.randrange(len(cols))] = cols[j]
        else:
            cols[j] = rng.choice(["", "x", cols[j].upper(), cols[j] + " ", "\u00e9" + cols[j],
                                  cols[j] + "\x1b[2J", "\x1b]0;title\x07" + cols[j]])
        lines[hi] = ",".join(cols)
    elif op == 7:  # comment lines that try to inject
        lines.insert(0, rng.choice([
            "# axis: X]=0 ;", "# axis: ../../escaped", "# axis: X\r\nM30",
            "# alpha_um_per_m_k: NaN", "# alpha_um_per_m_k: 1e308", "# units: parsecs",
            "# source: " + "A" * 100000, "# material_temperature_c: inf",
            "# source: \x1b[2J\x1b[31mred", "# axis: X\x1b[1A", "\x1b[2J,\x07,\x08",
        ]))
    elif op == 8:
        return mutate_bytes(data, rng)
    elif op == 9:  # line endings, BOM, NULs
        t = "\n".join(lines)
        choice = rng.randrange(3)
        if choice == 0:
            return t.replace("\n", "\r\n").encode()
        if choice == 1:
            return b"\xef\xbb\xbf" + t.encode()
        return t.encode().replace(b",", b",\x00", 1)
    elif op == 10:  # one very long line
        lines.insert(rng.randrange(1, max(2, len(lines))), "1," * rng.choice([1000, 200000]))
    else:  # a column's numbers scaled to extremes
        scale = rng.choice([1e150, 1e-150, -1, 1e6])
        out = []
        for l in lines:
            if l.startswith("#"):
                out.append(l)
                continue
            out.append(re.sub(r"(?<![\w.])-?\d+\.\d+(?:[eE][-+]?\d+)?",
                              lambda m: repr(float(m.group(0)) * scale), l))
        lines = out
    return "\n".join(lines).encode("utf-8", errors="replace")


def mutate_bytes(data: bytes, rng: random.Random) -> bytes:
    b = bytearray(data)
    op = rng.randrange(4)
    if op == 0 and b:
        return bytes(b[: rng.randrange(len(b))])
    if op == 1:
        for _ in range(rng.randrange(1, 30)):
            if b:
                b[rng.randrange(len(b))] ^= 1 << rng.randrange(8)
        return bytes(b)
    if op == 2 and len(b) > 64:
        i = rng.randrange(len(b) - 32)
        j = i + rng.randrange(1, min(4096, len(b) - i))
        return bytes(b[:i] + b[j:])
    return bytes(b) + bytes(rng.randrange(256) for _ in range(rng.randrange(1, 512)))


def limit():
    resource.setrlimit(resource.RLIMIT_AS, (MEMORY, MEMORY))
    os.setsid()


def echoed(out: str, m, inp_text: str) -> bool:
    """Whether the word is the input's own text echoed (a budget's title, or a whole quoted
    value such as a unit `unit = "+inf"` printed in the unit column), not a number."""
    before = out[max(0, m.start() - 6):m.end()]
    after = out[m.start():m.end() + 10]
    # The whitespace-delimited word holding the match, e.g. a unit `nan/°C`.
    start = out.rfind(" ", 0, m.start()) + 1
    end = min((i for i in (out.find(" ", m.end()), out.find("\n", m.end())) if i >= 0),
              default=len(out))
    if f'"{m.group(0)}"' in inp_text or f'"{out[start:end]}"' in inp_text:
        return True
    return any(len(c) > len(m.group(0)) + 4 and c in inp_text for c in (before, after))


def run_one(binary, args, work: Path, inp_text=""):
    """Runs one command line in `work` (its cwd); the findings, if any."""
    out_dir = work / "out"
    out_dir.mkdir()
    before = set(p for p in work.rglob("*"))
    argv = [binary] + args
    try:
        p = subprocess.run(argv, cwd=work / "cwd", stdin=subprocess.DEVNULL,
                           capture_output=True, timeout=DEADLINE_S, preexec_fn=limit)
    except subprocess.TimeoutExpired:
        return ["hang"], None, ""
    bad = []
    if p.returncode < 0:
        bad.append(f"signal {signal.Signals(-p.returncode).name}")
    elif p.returncode not in ALLOWED_EXIT:
        bad.append(f"exit {p.returncode}")
    err = p.stderr.decode(errors="replace")
    if "panicked" in err or "RUST_BACKTRACE" in err:
        bad.append("panic: " + err[-300:])
    for name, text in (("stdout", p.stdout.decode(errors="replace")), ("stderr", err)):
        c = CONTROL.search(text)
        if c:
            bad.append(f"control character in {name}: …{text[max(0, c.start() - 60):c.end() + 20]!r}")
    if p.returncode == 0:
        s = p.stdout.decode(errors="replace")
        m = NONFINITE.search(s)
        if m and not echoed(s, m, inp_text) and not any(
                w in " ".join(args).lower() for w in ("nan", "inf")):
            bad.append(f"non-finite in stdout: …{s[max(0, m.start() - 60):m.end() + 20]!r}")
    for f in out_dir.rglob("*"):
        if p.returncode != 0:
            bad.append(f"left after a failure: {f.name}")
        elif f.is_file() and f.suffix not in (".mcap", ".png", ".pdf"):
            t = f.read_bytes()[:50_000_000].decode(errors="replace")
            m = NONFINITE.search(t)
            if m and f.suffix not in (".html", ".svg"):
                bad.append(f"non-finite in {f.name}: …{t[max(0, m.start() - 60):m.end() + 20]!r}")
    after = set(q for q in work.rglob("*"))
    new = [q for q in after - before if out_dir not in q.parents and q != out_dir]
    if new:
        bad.append(f"written outside -o: {[str(q.relative_to(work)) for q in new][:3]}")
    return bad, p.returncode, err


def cases(rng, n):
    """n (command line with {i} {o} {x}, input bytes or None, label) cases."""
    all_seeds = seeds()
    by_kind = {}
    for k, name, data in all_seeds:
        by_kind.setdefault(k, []).append((name, data))
    for _ in range(n):
        r = rng.random()
        if r < 0.7:
            k, name, data = rng.choice(all_seeds)
            if not COMMANDS.get(k):
                continue
            yield rng.choice(COMMANDS[k]), mutate(data, rng), f"{name} mutated"
        elif r < 0.9:
            k, cmd = rng.choice(OPTIONS)
            v = rng.choice(BAD_NUMBERS)
            if k is None:
                yield cmd.replace("{v}", v), None, f"value {v!r}"
            elif k in by_kind:
                name, data = rng.choice(by_kind[k])
                yield cmd.replace("{v}", v), data, f"{name} with {v!r}"
        else:
            k = rng.choice([k for k in COMMANDS if COMMANDS[k]])
            data = bytes(rng.randrange(256) for _ in range(rng.randrange(0, 3000)))
            yield rng.choice(COMMANDS[k]), data, "random bytes"


def expand(cmd, inp, work):
    """The argv of a command line (names with spaces or newlines kept as one argument)."""
    parts = cmd.split(" ")  # {n} (a hostile name) is put in after the split: it may hold spaces
    return [p.replace("{i}", str(inp)).replace("{o}", str(work / "out"))
            .replace("{x}", str(EXAMPLES)) for p in parts]


def one(binary, i, cmd, data, label, keep):
    with tempfile.TemporaryDirectory() as t:
        work = Path(t)
        (work / "cwd").mkdir()
        inp = work / "in" / ("input.mcap" if "info" in cmd or "replay" in cmd or "recover" in cmd
                             else "input" + (".toml" if "uncertainty" in cmd else ".csv"))
        inp.parent.mkdir()
        if data is not None:
            inp.write_bytes(data)
        args = expand(cmd, inp, work)
        args = [x.replace("{n}", NAMES[i % len(NAMES)]) for x in args]
        text = data.decode(errors="replace") if data is not None else ""
        bad, code, err = run_one(binary, args, work, text)
        if bad and keep:
            d = Path(keep) / f"case{i:05}"
            d.mkdir(parents=True, exist_ok=True)
            if data is not None:
                (d / inp.name).write_bytes(data)
            (d / "cmd.txt").write_text(" ".join(args) + "\n" + "\n".join(bad) + "\n")
        return i, cmd, label, bad, code, err


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("binary")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--runs", type=int, default=2000)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--keep", default=None)
    ap.add_argument("--verbose", action="store_true", help="print the usage errors (exit 2)")
    a = ap.parse_args()
    rng = random.Random(a.seed)
    todo = list(cases(rng, a.runs))
    failures, codes = [], {}
    with cf.ThreadPoolExecutor(a.jobs) as ex:
        futs = [ex.submit(one, a.binary, i, c, d, l, a.keep) for i, (c, d, l) in enumerate(todo)]
        for f in cf.as_completed(futs):
            i, cmd, label, bad, code, err = f.result()
            key = " ".join(cmd.split(" ")[:2]).replace(" {i}", "")
            codes.setdefault(key, {})
            codes[key][code] = codes[key].get(code, 0) + 1
            if code == 2 and a.verbose:
                print(f"usage error: {cmd}: {err.strip()[:300]}")
            if bad:
                failures.append((i, cmd, label, bad))
    print(f"{len(todo)} runs, {len(failures)} broke a rule")
    for k in sorted(codes):
        print(f"  {k}: exit codes {dict(sorted(codes[k].items(), key=str))}")
    for i, cmd, label, bad in sorted(failures)[:40]:
        print(f"  case {i}: {cmd}  [{label}]\n      " + "\n      ".join(b[:400] for b in bad))
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
