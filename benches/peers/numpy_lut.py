#!/usr/bin/env python3
"""A vectorised NumPy look-up-table match of every pixel's spectra over thickness, the index
given: the kind of script a researcher writes.

    python3 benches/peers/numpy_lut.py CAPTURE_DIR [--step-nm 1.0]

The table holds the model's band reflectance at every angle and band for thicknesses on a
grid over the capture's search range (`--step-nm`); each pixel takes the grid thickness of
least squared difference (one matrix product for all pixels, in chunks), refined by a
parabola through that point and its neighbours. A pixel is valid when its spectra are
finite and its residual is under five times the median one. Prints one JSON line:
`{seconds, load_seconds, pixels, mae_nm, valid}` (`seconds`: table and match, after
reading and calibrating).
"""

import argparse
import time

import numpy as np

from capture import Capture, report


def lut_match(cap, spectra, step_nm):
    """Per pixel: the refined thickness and its residual sum of squares."""
    lo, hi = cap.thickness_range
    grid = np.arange(lo, hi + 0.5 * step_nm, step_nm)
    table = np.concatenate([cap.model(grid[i : i + 256]) for i in range(0, grid.size, 256)])
    norms = np.einsum("ij,ij->i", table, table)
    best = np.empty(spectra.shape[0])
    resid = np.empty(spectra.shape[0])
    for s in range(0, spectra.shape[0], 2048):
        x = spectra[s : s + 2048]
        sse = norms[None, :] - 2.0 * (x @ table.T) + np.einsum("ij,ij->i", x, x)[:, None]
        k = np.clip(np.argmin(sse, axis=1), 1, grid.size - 2)
        rows = np.arange(x.shape[0])
        y0, y1, y2 = sse[rows, k - 1], sse[rows, k], sse[rows, k + 1]
        curv = y0 - 2.0 * y1 + y2
        shift = np.where(curv > 0, 0.5 * (y0 - y2) / np.where(curv > 0, curv, 1.0), 0.0)
        best[s : s + 2048] = grid[k] + np.clip(shift, -1.0, 1.0) * step_nm
        resid[s : s + 2048] = y1
    return best, resid


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("capture")
    ap.add_argument("--step-nm", type=float, default=1.0)
    args = ap.parse_args()
    t0 = time.perf_counter()
    cap = Capture(args.capture)
    load = time.perf_counter() - t0
    t1 = time.perf_counter()
    finite = np.isfinite(cap.spectra).all(axis=1)
    spectra = np.where(np.isfinite(cap.spectra), cap.spectra, 0.0)
    best, resid = lut_match(cap, spectra, args.step_nm)
    seconds = time.perf_counter() - t1
    valid = finite & (resid < 5.0 * np.median(resid[finite]))
    print(report(seconds, load, best, cap.truth_nm, valid))


if __name__ == "__main__":
    main()
