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


if __name__ == "__main__":
    sys.exit(main())
