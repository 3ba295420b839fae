"""What both peers share: a small NumPy reader of a filmscope capture (capture.toml and
ENVI cubes of any interleave and byte order, float reflectance or raw counts calibrated
with their white and dark references), the film's index as the scene's truth gives it, and
the thin-film forward model (the Airy sum of one film on a substrate, s, p or unpolarised,
averaged over each band's Gaussian passband) written as a researcher would, in NumPy.
"""

import json
import math
import os
import tomllib

import numpy as np

ENVI_TYPES = {4: np.float32, 5: np.float64, 2: np.int16, 12: np.uint16}


def read_header(path):
    """The ENVI header at `path` as a dict of lower-case keys (lists for `{...}` values)."""
    text = open(path).read()
    out, key, buf = {}, None, None
    for line in text.splitlines()[1:]:
        if buf is not None:
            buf += " " + line
            if "}" in line:
                out[key] = buf
                buf = None
            continue
        if "=" not in line:
            continue
        k, v = line.split("=", 1)
        key, v = k.strip().lower(), v.strip()
        if v.startswith("{") and "}" not in v:
            buf = v
        else:
            out[key] = v
    for k, v in out.items():
        if v.startswith("{"):
            out[k] = [x.strip() for x in v.strip("{} ").split(",") if x.strip()]
    return out


def read_cube(hdr_path):
    """The cube as float64 `[line, band, sample]`."""
    h = read_header(hdr_path)
    samples, lines, bands = int(h["samples"]), int(h["lines"]), int(h["bands"])
    dtype = np.dtype(ENVI_TYPES[int(h["data type"])])
    dtype = dtype.newbyteorder(">" if h.get("byte order", "0") == "1" else "<")
    base = hdr_path[: -len(".hdr")]
    data_path = next(p for p in (base + ".img", base + ".raw", base + ".dat", base) if os.path.exists(p))
    raw = np.fromfile(data_path, dtype=dtype, offset=int(h.get("header offset", "0")))
    inter = h.get("interleave", "bsq").lower()
    shape = {"bsq": (bands, lines, samples), "bil": (lines, bands, samples), "bip": (lines, samples, bands)}[inter]
    cube = raw[: bands * lines * samples].reshape(shape)
    cube = {"bsq": cube.transpose(1, 0, 2), "bil": cube, "bip": cube.transpose(0, 2, 1)}[inter]
    return cube.astype(np.float64), h


class Capture:
    """A capture's calibrated reflectance `spectra[pixel, angle * bands + band]`, its
    geometry and optics, the true thickness map and the film's true index."""

    def __init__(self, capture_dir):
        path = capture_dir if capture_dir.endswith(".toml") else os.path.join(capture_dir, "capture.toml")
        root = os.path.dirname(path)
        cap = tomllib.load(open(path, "rb"))
        sample = cap["sample"]
        self.ambient = float(sample.get("ambient_index", 1.0))
        self.substrate = float(sample["substrate_index"])
        self.polarization = sample.get("polarization", "s")
        self.thickness_range = cap.get("search", {}).get("thickness_range_nm", [50.0, 2000.0])
        angles = sorted(cap["angle"], key=lambda a: a["incidence_deg"])
        self.angles_deg = [float(a["incidence_deg"]) for a in angles]
        blocks = []
        for a in angles:
            cube, h = read_cube(os.path.join(root, a["cube"]))
            if "white" in a:
                white, _ = read_cube(os.path.join(root, a["white"]))
                dark = read_cube(os.path.join(root, a["dark"]))[0] if "dark" in a else 0.0
                with np.errstate(divide="ignore", invalid="ignore"):
                    span = white - dark
                    cube = np.where(span > 0, a.get("white_reflectance", 1.0) * (cube - dark) / span, np.nan)
            blocks.append(cube)  # [line, band, sample]
            self.bands_nm = np.array([float(x) for x in h["wavelength"]])
            self.fwhm_nm = np.array([float(x) for x in h["fwhm"]]) if "fwhm" in h else None
        self.lines, nb, self.samples = blocks[0].shape
        # [pixel, angle, band] -> [pixel, angle * bands + band]
        stack = np.stack([b.transpose(0, 2, 1).reshape(-1, nb) for b in blocks], axis=1)
        self.spectra = stack.reshape(stack.shape[0], -1)
        truth = json.load(open(os.path.join(root, "truth.json")))
        self.dispersion = truth.get("dispersion")
        self.index_550 = float(truth["refractive_index"])
        t, _ = read_cube(os.path.join(root, truth["thickness_map"]))
        self.truth_nm = t[:, 0, :].reshape(-1)

    def film_index(self, lam_nm):
        """The film's true index at `lam_nm` (its dispersion from truth.json)."""
        d = self.dispersion
        l = np.asarray(lam_nm) * 1e-3
        if d is None:
            return np.full_like(l, self.index_550, dtype=np.float64)
        if d["model"] == "cauchy":
            return d["a"] + d["b_um2"] / l**2 + d.get("c_um4", 0.0) / l**4
        n2 = d["a"] + sum(b * l**2 / (l**2 - c**2) for b, c in zip(d["b"], d["c_um"]) if b != 0.0)
        return np.sqrt(n2)

    def model(self, thickness_nm, nodes=15):
        """Band reflectance `[thickness, angle * bands + band]` of films of `thickness_nm`."""
        d = np.atleast_1d(np.asarray(thickness_nm, dtype=np.float64))
        fwhm = self.fwhm_nm if self.fwhm_nm is not None else np.gradient(self.bands_nm)
        x = np.linspace(-1.5, 1.5, nodes)
        lam = self.bands_nm[:, None] + fwhm[:, None] * x[None, :]  # [band, node]
        w = np.exp(-4.0 * math.log(2.0) * x**2)
        w = w / w.sum()
        n0, n2 = self.ambient, self.substrate
        n1 = self.film_index(lam)
        out = []
        for theta in self.angles_deg:
            beta = n0 * math.sin(math.radians(theta))
            k0 = np.sqrt(complex(n0**2 - beta**2))
            k1 = np.sqrt((n1**2 - beta**2).astype(np.complex128))
            k2 = np.sqrt(complex(n2**2 - beta**2))
            pols = ["s", "p"] if self.polarization.startswith("u") else [self.polarization]
            r_total = 0.0
            phase = np.exp(1j * 4.0 * math.pi * d[:, None, None] * k1[None] / lam[None])
            for pol in pols:
                if pol == "s":
                    r01 = (k0 - k1) / (k0 + k1)
                    r12 = (k1 - k2) / (k1 + k2)
                else:
                    r01 = (n1**2 * k0 - n0**2 * k1) / (n1**2 * k0 + n0**2 * k1)
                    r12 = (n2**2 * k1 - n1**2 * k2) / (n2**2 * k1 + n1**2 * k2)
                r = (r01 + r12 * phase) / (1.0 + r01 * r12 * phase)
                r_total = r_total + np.abs(r) ** 2
            out.append((r_total / len(pols)) @ w)  # [thickness, band]
        return np.concatenate(out, axis=1)


def report(seconds, load_seconds, estimate_nm, truth_nm, valid):
    """The JSON line both peers print."""
    ok = valid & np.isfinite(estimate_nm)
    mae = float(np.mean(np.abs(estimate_nm[ok] - truth_nm[ok]))) if ok.any() else float("nan")
    return json.dumps(
        {
            "seconds": seconds,
            "load_seconds": load_seconds,
            "pixels": int(estimate_nm.size),
            "mae_nm": mae,
            "valid": float(ok.mean()),
        }
    )
