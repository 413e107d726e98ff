#!/usr/bin/env python3
"""NumPy reference for the CapBall Monte Carlo benchmark (benches/capball_vs_numpy.rs).

The same computation per trial: 2421 normal draws (807 poses x 3 directions) scaled by the
per-row standard deviation, one 14 x 2421 projection by the pseudo-inverse, plus the cyclic
drift's projection (3 harmonics, random phase per trial). Vectorised NumPy in batches, which is
how one would write it in NumPy. The Jacobian is a random 2421 x 14 matrix: the cost does not
depend on its values.

    python3 uncertainty/benches/py/capball_mc.py [--trials 200000] [--threads 1] [--reduced]

`--reduced` draws the per-point noise in parameter space instead (14 normals times a square
root of J+ Sigma J+^T, exact for Gaussian per-point noise), the same shortcut as the Rust
`CapballMc::with_reduced_noise`. Prints trials per CPU-second;
`cargo bench -p metrolog-uncertainty --bench capball_vs_numpy` runs this script and the Rust code
in one run and prints the ratios.

`--end-to-end --sequences A,B,C,D` does the whole work of `metrolog identify capball
--uncertainty mc` (uncertainty::capball::source_widths) instead: four adaptive Monte Carlo runs
(all sources, then drift, sensor and frame alone) of the reduced model, each of the given number
of sequences of 10 000 trials (the counts the Rust run needed, so both do the same trials), with
JCGM 101 7.9's per-sequence statistics (mean, standard deviation and the 95 % symmetric interval
of each of the 14 outputs, np.partition), the stabilisation check after each sequence (running
sums for u(y), the standard deviations of the sequence statistics), and at the end the mean,
standard deviation, symmetric interval (np.partition), shortest interval (np.sort) and the
correlation matrix (np.corrcoef) of all values; the model set-up (pseudo-inverse by SVD, root
of the covariance) is timed too. Prints the wall-clock and CPU seconds of the whole.
"""

import argparse
import os
import sys
import time


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--trials", type=int, default=200_000)
    ap.add_argument("--batch", type=int, default=500)
    ap.add_argument("--threads", type=int, default=1, help="BLAS threads (1 = one core)")
    ap.add_argument("--reduced", action="store_true", help="noise drawn in parameter space")
    ap.add_argument("--end-to-end", action="store_true", help="the whole source_widths run")
    ap.add_argument("--sequences", default="", help="sequences per run (end to end), A,B,C,D")
    a = ap.parse_args()
    for v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[v] = str(a.threads)
    import numpy as np  # after the thread settings

    rng = np.random.default_rng(1)
    n_rows, n_par = 3 * 807, 14
    j = rng.standard_normal((n_rows, n_par))
    pinv = np.linalg.pinv(j)  # 14 x 2421
    sigma = np.tile(np.sqrt([0.1**2 + 0.3**2] * 3), 807)
    p_hat = rng.standard_normal(n_par)
    harmonics = [(k, rng.standard_normal(n_par), rng.standard_normal(n_par)) for k in (1, 2, 3)]

    scaled = pinv * sigma
    w, v = np.linalg.eigh(scaled @ scaled.T)
    root = v * np.sqrt(np.clip(w, 0, None))  # 14 x 14

    def batch(m: int) -> np.ndarray:
        if a.reduced:
            p = rng.standard_normal((m, n_par)) @ root.T + p_hat
        else:
            e = rng.standard_normal((m, n_rows)) * sigma
            p = e @ pinv.T + p_hat
        phi = rng.random(m) * 2 * np.pi
        for k, a_k, b_k in harmonics:
            p += np.cos(k * phi)[:, None] * a_k + np.sin(k * phi)[:, None] * b_k
        return p

    if a.end_to_end:
        return end_to_end(np, rng, a)

    batch(a.batch)  # warm-up
    done = 0
    t0 = time.perf_counter()
    c0 = time.process_time()
    while done < a.trials:
        m = min(a.batch, a.trials - done)
        batch(m)
        done += m
    wall = time.perf_counter() - t0
    cpu = time.process_time() - c0
    print(f"numpy {np.__version__}: {done} trials, {wall:.2f} s wall, {cpu:.2f} s CPU")
    print(f"trials per second (wall): {done / wall:.0f}")
    print(f"trials per CPU-second: {done / cpu:.0f}")
    return 0


def tolerance(np, u, ndig=2):
    """JCGM 101 7.9.2: u = c * 10^l with c an ndig-digit integer; delta = 10^l / 2."""
    l = np.floor(np.log10(u)) - ndig + 1
    return 0.5 * 10.0**l


def adaptive_run(np, rng, root, harmonics, p_hat, n_seq, p=0.95, m=10_000):
    """One adaptive Monte Carlo run of n_seq sequences; returns the final statistics."""
    n_par = p_hat.size
    q = int(np.floor(p * m + 0.5))
    r = (m - q + 1) // 2  # 1-based start of the symmetric interval
    seq_stats = []
    values = []
    s1 = np.zeros(n_par)
    s2 = np.zeros(n_par)
    n = 0
    stable = False
    for h in range(n_seq):
        y = rng.standard_normal((m, n_par)) @ root.T + p_hat
        phi = rng.random(m) * 2 * np.pi
        for k, a_k, b_k in harmonics:
            y += np.cos(k * phi)[:, None] * a_k + np.sin(k * phi)[:, None] * b_k
        part = np.partition(y, [r - 1, r - 1 + q], axis=0)
        seq_stats.append(np.stack([y.mean(0), y.std(0, ddof=1), part[r - 1], part[r - 1 + q]]))
        values.append(y)
        n += m
        s1 += y.sum(0)
        s2 += (y * y).sum(0)
        if h >= 1:
            u_all = np.sqrt(np.maximum(s2 - s1 * s1 / n, 0) / (n - 1))
            st = np.array(seq_stats)
            two_s = 2 * st.std(0, ddof=1) / np.sqrt(h + 1)
            stable = bool((two_s <= tolerance(np, np.where(u_all > 0, u_all, 1.0))).all())
    y = np.concatenate(values)
    big_m = y.shape[0]
    q = int(np.floor(p * big_m + 0.5))
    r = (big_m - q + 1) // 2
    part = np.partition(y, [r - 1, r - 1 + q], axis=0)
    sym = (part[r - 1], part[r - 1 + q])
    srt = np.sort(y, axis=0)
    widths = srt[q:] - srt[: big_m - q]
    best = widths.argmin(axis=0)
    cols = np.arange(n_par)
    shortest = (srt[best, cols], srt[best + q, cols])
    corr = np.corrcoef(y, rowvar=False)
    return y.mean(0), y.std(0, ddof=1), sym, shortest, corr, stable


def end_to_end(np, rng, a):
    seqs = [int(v) for v in a.sequences.split(",") if v]
    if len(seqs) != 4:
        print("--end-to-end needs --sequences A,B,C,D (all sources, drift, sensor, frame)")
        return 2
    t0 = time.perf_counter()
    c0 = time.process_time()
    n_rows, n_par = 3 * 807, 14
    j = rng.standard_normal((n_rows, n_par))
    p_hat = rng.standard_normal(n_par)
    harmonics = [(k, rng.standard_normal(n_par), rng.standard_normal(n_par)) for k in (1, 2, 3)]
    sensor = np.tile([0.1] * 3, 807)
    frame = np.tile([0.3] * 3, 807)
    runs = [(sensor, frame, harmonics), (0 * sensor, 0 * frame, harmonics),
            (sensor, 0 * frame, []), (0 * sensor, frame, [])]
    widths = []
    for (s_sensor, s_frame, harm), n_seq in zip(runs, seqs):
        pinv = np.linalg.pinv(j)
        sigma = np.sqrt(s_sensor**2 + s_frame**2)
        scaled = pinv * sigma
        w, v = np.linalg.eigh(scaled @ scaled.T)
        root = v * np.sqrt(np.clip(w, 0, None))
        _, _, sym, _, _, _ = adaptive_run(np, rng, root, harm, p_hat, n_seq)
        widths.append(sym[1] - sym[0])
    wall = time.perf_counter() - t0
    cpu = time.process_time() - c0
    print(f"numpy {np.__version__}: end to end, sequences {seqs}, width[0] {widths[0][0]:.3f}")
    print(f"end-to-end seconds (wall): {wall:.3f}")
    print(f"end-to-end seconds (CPU): {cpu:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
