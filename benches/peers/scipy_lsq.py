#!/usr/bin/env python3
"""A SciPy `least_squares` fit of every pixel's thickness over all its spectra, the index
given, started from the nearest point of a coarse look-up table: the kind of script a
researcher writes.

    python3 benches/peers/scipy_lsq.py CAPTURE_DIR [--max-pixels N] [--coarse-step-nm 5]

Each pixel's residual is the model's band reflectance at every angle and band minus the
measured one; `least_squares` (trust region reflective, 2-point Jacobian) fits the
thickness within the capture's search range. `--max-pixels` fits an evenly strided subset
(the time is then per pixel fitted). A pixel is valid when its spectra are finite, the fit
converged and its residual is under five times the median one. Prints one JSON line:
`{seconds, load_seconds, pixels, mae_nm, valid}` (`seconds`: the coarse table and the
fits, after reading and calibrating; `pixels`: the pixels fitted).
"""

import argparse
import time

import numpy as np
from scipy.optimize import least_squares

from capture import Capture, report


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("capture")
    ap.add_argument("--max-pixels", type=int, default=0)
    ap.add_argument("--coarse-step-nm", type=float, default=5.0)
    args = ap.parse_args()
    t0 = time.perf_counter()
    cap = Capture(args.capture)
    load = time.perf_counter() - t0
    n = cap.spectra.shape[0]
    stride = max(1, -(-n // args.max_pixels)) if args.max_pixels > 0 else 1
    pick = np.arange(0, n, stride)
    spectra = cap.spectra[pick]
    truth = cap.truth_nm[pick]
    t1 = time.perf_counter()
    lo, hi = cap.thickness_range
    grid = np.arange(lo, hi + 0.5 * args.coarse_step_nm, args.coarse_step_nm)
    table = cap.model(grid)
    finite = np.isfinite(spectra).all(axis=1)
    best = np.full(pick.size, np.nan)
    cost = np.full(pick.size, np.inf)
    ok = np.zeros(pick.size, dtype=bool)
    for i in np.flatnonzero(finite):
        y = spectra[i]
        start = grid[np.argmin(((table - y[None, :]) ** 2).sum(axis=1))]
        fit = least_squares(lambda d: cap.model(d[0])[0] - y, [start], bounds=([lo], [hi]))
        best[i], cost[i], ok[i] = fit.x[0], 2.0 * fit.cost, fit.success
    seconds = time.perf_counter() - t1
    valid = finite & ok & (cost < 5.0 * np.median(cost[finite]))
    print(report(seconds, load, best, truth, valid))


if __name__ == "__main__":
    main()
