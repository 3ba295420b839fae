#!/usr/bin/env python3
"""Opens a simulated capture and an estimate with Spectral Python and checks what it reads.

    python3 tests/spectral_interop.py CAPTURE_DIR ESTIMATE_DIR

Run by .ci/run after `filmscope simulate` and `filmscope estimate`.
"""

import json
import math
import os
import sys

import numpy as np
import spectral.io.envi as envi


def main(cap, est):
    truth = json.load(open(os.path.join(cap, "truth.json")))
    w, h = truth["width"], truth["height"]
    n = 0
    for name in sorted(os.listdir(cap)):
        if name.endswith(".hdr"):
            img = envi.open(os.path.join(cap, name))
            assert img.shape[:2] == (h, w), (name, img.shape)
            wl = [float(x) for x in img.metadata["wavelength"]]
            assert len(wl) == img.shape[2] and wl == sorted(wl), name
            a = img.load()
            assert np.isfinite(a).all(), name
            n += 1
    t = envi.open(os.path.join(cap, "truth", "thickness_nm.hdr")).load()
    assert t.shape[:2] == (h, w) and np.isfinite(t).all()
    m = envi.open(os.path.join(est, "thickness_nm.hdr")).load()
    assert m.shape[:2] == (h, w)
    s = json.load(open(os.path.join(est, "summary.json")))
    valid = np.isfinite(m).mean()
    assert math.isclose(valid, s["valid_fraction"], abs_tol=1e-9), (valid, s["valid_fraction"])
    f = envi.open(os.path.join(est, "flags.hdr")).load()
    assert f.shape[:2] == (h, w)
    print(f"spectral_interop: {n} capture cubes, truth, thickness ({valid:.3f} valid) and flags maps open in Spectral Python")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
