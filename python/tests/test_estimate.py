"""filmscope.estimate: on a capture (the CLI's maps bit for bit) and on arrays."""

import json
import re
import subprocess
from pathlib import Path

import numpy as np
import pytest

import filmscope
from conftest import small_scene


def read_envi_map(hdr: Path) -> np.ndarray:
    """A one-band ENVI map (float32 or uint16) as written by filmscope."""
    text = hdr.read_text()
    key = lambda k: re.search(rf"^{k}\s*=\s*(\S+)", text, re.M | re.I).group(1)
    samples, lines, dtype = int(key("samples")), int(key("lines")), int(key("data type"))
    order = ">" if int(key("byte order")) == 1 else "<"
    dt = {4: np.dtype(order + "f4"), 12: np.dtype(order + "u2")}[dtype]
    data = np.fromfile(hdr.with_suffix(".img"), dtype=dt)
    return data.reshape(lines, samples)


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    d = tmp_path_factory.mktemp("cap")
    # Raw counts with white and dark references, as the rig writes them.
    scene = small_scene(sensor={"width": 40, "height": 24})
    made = filmscope.simulate(scene, d / "cap", seed=3)
    assert Path(made["capture"]).name == "capture.toml"
    return d / "cap"


def test_capture_estimate_equals_cli_bit_for_bit(capture, tmp_path, cli):
    out = tmp_path / "cli"
    subprocess.run(cli + ["estimate", str(capture), "--out", str(out)], check=True, capture_output=True)
    r = filmscope.estimate(capture)
    for name, arr in [
        ("thickness_nm", r.thickness_nm),
        ("confidence", r.confidence),
        ("thickness_sigma_nm", r.sigma_nm),
    ]:
        want = read_envi_map(out / f"{name}.hdr")
        assert arr.dtype == np.float32 and arr.shape == want.shape
        assert np.array_equal(arr, want, equal_nan=True), name
    flags = read_envi_map(out / "flags.hdr")
    assert np.array_equal(r.flags, flags.astype(np.uint16))
    summary = json.loads((out / "summary.json").read_text())
    assert r.summary["refractive_index"] == summary["refractive_index"]
    assert r.summary["dispersion"] == summary["dispersion"]
    assert r.dispersion["n_table"]["n"] == summary["dispersion"]["n_table"]["n"]
    # And it is a real estimate: the truth is 1.38 and 390-450 nm.
    truth = read_envi_map(capture / "truth" / "thickness_nm.hdr")
    assert abs(r.n_550 - 1.38) < 0.01
    valid = np.isfinite(r.thickness_nm)
    assert valid.mean() > 0.9
    assert np.nanmean(np.abs(r.thickness_nm - truth)[valid]) < 5.0


def test_capture_estimate_writes_out_like_the_cli(capture, tmp_path):
    r = filmscope.estimate(capture, out=tmp_path / "py")
    assert (tmp_path / "py" / "summary.json").exists()
    assert np.array_equal(read_envi_map(tmp_path / "py" / "thickness_nm.hdr"), r.thickness_nm, equal_nan=True)


def test_array_estimate_recovers_thickness():
    sim = filmscope.simulate(small_scene(), seed=5)
    cube = sim["reflectance"]
    assert cube.shape == (4, 24, 40, 151) and cube.dtype == np.float32
    r = filmscope.estimate(
        cube.astype(np.float64),
        sim["wavelengths_nm"],
        sim["angles_deg"],
        fwhm_nm=sim["fwhm_nm"],
        substrate=sim["substrate"],
        polarization=sim["polarization"],
    )
    assert r.thickness_nm.shape == (24, 40)
    assert abs(r.n_550 - 1.38) < 0.005, r
    valid = np.isfinite(r.thickness_nm)
    assert valid.mean() > 0.95
    err = np.abs(r.thickness_nm - sim["thickness_nm"])[valid]
    assert err.mean() < 2.0, err.mean()
    # Angles given in another order, and the cube permuted alike, give the same maps.
    perm = [2, 0, 3, 1]
    r2 = filmscope.estimate(
        cube[perm], sim["wavelengths_nm"], sim["angles_deg"][perm],
        fwhm_nm=sim["fwhm_nm"], substrate=sim["substrate"], polarization=sim["polarization"],
    )
    assert np.array_equal(r.thickness_nm, r2.thickness_nm, equal_nan=True)


def test_array_estimate_with_a_wrong_substrate_is_worse():
    sim = filmscope.simulate(small_scene(), seed=5)
    args = (sim["reflectance"], sim["wavelengths_nm"], sim["angles_deg"])
    good = filmscope.estimate(*args, fwhm_nm=4.0, substrate=1.65)
    bad = filmscope.estimate(*args, fwhm_nm=4.0, substrate=1.45)
    # Flagged (no index, every pixel NaN) or farther from the truth, never as good.
    assert not abs(bad.n_550 - 1.38) <= abs(good.n_550 - 1.38)
    assert bad.summary["valid_fraction"] < good.summary["valid_fraction"] or bad.n_550 != bad.n_550


def test_bad_inputs_raise_one_line(tmp_path):
    with pytest.raises(filmscope.FilmscopeError, match="capture.toml"):
        filmscope.estimate(tmp_path)
    cube = np.zeros((3, 4, 5, 20), dtype=np.float32)
    wl = np.linspace(400, 700, 20)
    with pytest.raises(filmscope.FilmscopeError, match="wavelengths_nm"):
        filmscope.estimate(cube, wl[:10], [10, 20, 30])
    with pytest.raises(filmscope.FilmscopeError, match="angles_deg"):
        filmscope.estimate(cube, wl, [10, 20])
    with pytest.raises(filmscope.FilmscopeError, match="4 dimensions"):
        filmscope.estimate(cube[0], wl, [10, 20, 30])
    with pytest.raises(filmscope.FilmscopeError, match="method"):
        filmscope.estimate(cube, wl, [10, 20, 30], method="magic")
    with pytest.raises(filmscope.FilmscopeError, match="substrate"):
        filmscope.estimate(cube, wl, [10, 20, 30], substrate="unobtainium")


def _hfo2_film_side_reflectance():
    """The measured HfO2-on-fused-silica transmittance fixture as the film side's reflectance
    (a lossless film, the substrate's bare back face summed incoherently), 400-720 nm."""
    path = Path(__file__).resolve().parents[2] / "tests/fixtures/measured/hfo2-on-fused-silica-transmittance.txt"
    data = np.loadtxt(path)
    keep = (data[:, 0] >= 400) & (data[:, 0] <= 720)
    wl, t = data[keep, 0][::2], data[keep, 1][::2] / 100.0
    x2 = (wl / 1000.0) ** 2
    n2 = 1 + 0.6961663 * x2 / (x2 - 0.0684043**2) + 0.4079426 * x2 / (x2 - 0.1162414**2) + 0.8974794 * x2 / (x2 - 9.896161**2)
    rb = ((np.sqrt(n2) - 1) / (np.sqrt(n2) + 1)) ** 2
    return wl, (1 - rb - t) / (1 - rb - t * rb)


def test_a_measured_spectrum_at_one_angle():
    """One angle from Python: the measured HfO2 film gets every pixel, its index and
    thickness within the published fits' spread, and no index when judged against the noise
    alone (model_error=0); the rig's terms (rig_tolerance) widen the index sigma only."""
    wl, r = _hfo2_film_side_reflectance()
    rng = np.random.default_rng(3)
    cube = r[None, None, None, :] + 2.8e-4 * rng.standard_normal((1, 12, 16, len(wl)))
    kw = dict(fwhm_nm=2.0, substrate="sio2", polarization="unpolarized")
    res = filmscope.estimate(cube, wl, [0.0], **kw)
    assert 1.995 <= res.summary["refractive_index"] <= 2.015
    assert 185.0 <= np.nanmedian(res.thickness_nm) <= 195.0
    assert np.isfinite(res.thickness_nm).all()
    strict = filmscope.estimate(cube, wl, [0.0], model_error=0.0, **kw)
    assert not np.isfinite(strict.thickness_nm).any()
    with pytest.raises(filmscope.FilmscopeError, match="model_error"):
        filmscope.estimate(cube, wl, [0.0], model_error=0.5, **kw)
    # The rig's terms widen the index sigma and change nothing else.
    stat = filmscope.estimate(cube, wl, [0.0], rig_tolerance=0.0, **kw)
    assert stat.summary["refractive_index"] == res.summary["refractive_index"]
    assert np.array_equal(stat.thickness_nm, res.thickness_nm, equal_nan=True)
    assert res.summary["refractive_index_sigma"] > stat.summary["refractive_index_sigma"]
    with pytest.raises(filmscope.FilmscopeError, match="rig_tolerance"):
        filmscope.estimate(cube, wl, [0.0], rig_tolerance=-1.0, **kw)


def test_a_declared_bare_back_face_from_tmm_spectra():
    """Spectra of MgF2 on glass with its bare back face, made by tmm's incoherent stack (not
    filmscope's model): declared, the index and thickness come back; undeclared, the estimate
    is refused or right."""
    tmm = pytest.importorskip("tmm")
    import math

    wl = np.arange(420.0, 721.0, 3.0)
    angles = np.array([10.0, 30.0, 50.0])
    thick = np.linspace(440.0, 520.0, 12)

    def r(pol, d, a, l):
        return tmm.inc_tmm(pol, [1.0, 1.38, 1.52, 1.0], [np.inf, d, 1e6, np.inf],
                           ["i", "c", "i", "i"], math.radians(a), l)["R"]

    cols = np.array([[[r("s", d, a, l) for l in wl] for d in thick] for a in angles])
    rng = np.random.default_rng(3)
    cube = np.repeat(cols[:, None, :, :], 8, axis=1) + rng.normal(0.0, 2e-4, (3, 8, 12, len(wl)))
    args = (cube, wl, angles)
    declared = filmscope.estimate(*args, fwhm_nm=0.5, substrate=1.52, back_face="bare")
    assert abs(declared.n_550 - 1.38) < 0.003, declared
    valid = np.isfinite(declared.thickness_nm)
    assert valid.mean() > 0.95
    err = np.abs(declared.thickness_nm - thick[None, :])[valid]
    assert err.mean() < 1.0, err.mean()
    assert declared.summary["sample"]["back_face"] == "bare"
    plain = filmscope.estimate(*args, fwhm_nm=0.5, substrate=1.52)
    assert plain.summary["valid_fraction"] == 0.0 or abs(plain.n_550 - 1.38) < 0.01, plain
    with pytest.raises(filmscope.FilmscopeError, match="back_face"):
        filmscope.estimate(*args, fwhm_nm=0.5, substrate=1.52, back_face="frosted")


# Crystalline silicon at 300 K, M. A. Green, Sol. Energ. Mat. Sol. Cells 92, 1305 (2008),
# Table 1 (as refractiveindex.info lists it): wavelength nm, n, k.
GREEN_SI = np.array([
    (390, 6.039, 0.445), (400, 5.613, 0.296), (410, 5.330, 0.227), (420, 5.119, 0.176),
    (430, 4.949, 0.138), (440, 4.812, 0.107), (450, 4.691, 0.0863), (460, 4.587, 0.0714),
    (470, 4.497, 0.0621), (480, 4.419, 0.0550), (490, 4.350, 0.0491), (500, 4.294, 0.0442),
    (510, 4.241, 0.0394), (520, 4.193, 0.0364), (530, 4.151, 0.0331), (540, 4.112, 0.0303),
    (550, 4.077, 0.0280), (560, 4.045, 0.0258), (570, 4.015, 0.0241), (580, 3.988, 0.0225),
    (590, 3.963, 0.0211), (600, 3.940, 0.0199), (610, 3.918, 0.0184), (620, 3.898, 0.0174),
    (630, 3.879, 0.0164), (640, 3.861, 0.0154), (650, 3.844, 0.0144), (660, 3.828, 0.0135),
    (670, 3.813, 0.0127), (680, 3.798, 0.0119), (690, 3.784, 0.0112), (700, 3.772, 0.0105),
    (710, 3.759, 0.0101), (720, 3.748, 0.0096), (730, 3.737, 0.0089),
])


def test_an_oxide_on_silicon_from_tmm_spectra():
    """Spectra of a 1.46 film on silicon made by tmm (complex substrate index, not filmscope's
    model): with substrate="si" the index and thickness come back; taken as a clear
    substrate of silicon's index at 550 nm, the estimate is refused or worse."""
    tmm = pytest.importorskip("tmm")
    import math

    wl = np.arange(400.0, 721.0, 4.0)
    angles = np.array([10.0, 35.0, 60.0])
    thick = np.linspace(560.0, 640.0, 12)
    n_si = np.interp(wl, GREEN_SI[:, 0], GREEN_SI[:, 1])
    k_si = np.interp(wl, GREEN_SI[:, 0], GREEN_SI[:, 2])

    def r(d, a, i):
        stack = [1.0, 1.46, n_si[i] + 1j * k_si[i]]
        return tmm.coh_tmm("s", stack, [np.inf, d, np.inf], math.radians(a), wl[i])["R"]

    cols = np.array([[[r(d, a, i) for i in range(len(wl))] for d in thick] for a in angles])
    rng = np.random.default_rng(5)
    cube = np.repeat(cols[:, None, :, :], 8, axis=1) + rng.normal(0.0, 2e-4, (3, 8, 12, len(wl)))
    got = filmscope.estimate(cube, wl, angles, fwhm_nm=0.5, substrate="si")
    assert abs(got.n_550 - 1.46) < 0.003, got
    valid = np.isfinite(got.thickness_nm)
    assert valid.mean() > 0.95
    err = np.abs(got.thickness_nm - thick[None, :])[valid]
    assert err.mean() < 1.0, err.mean()
    clear = filmscope.estimate(cube, wl, angles, fwhm_nm=0.5, substrate=4.077)
    worse = np.nanmean(np.abs(clear.thickness_nm - thick[None, :])) if np.isfinite(clear.thickness_nm).any() else np.inf
    assert clear.summary["valid_fraction"] == 0.0 or worse > err.mean(), clear


def test_a_silicon_film_of_given_nk_from_tmm_spectra():
    """Spectra of a silicon film on glass made by tmm (the film's complex index): measured
    with film_index="si" (n and k given) the thickness comes back within 1 nm at every
    pixel, in s, p and unpolarised light."""
    tmm = pytest.importorskip("tmm")
    import math

    wl = np.arange(420.0, 721.0, 5.0)
    angles = np.array([10.0, 40.0, 60.0])
    thick = np.linspace(140.0, 170.0, 10)
    n_si = np.interp(wl, GREEN_SI[:, 0], GREEN_SI[:, 1])
    k_si = np.interp(wl, GREEN_SI[:, 0], GREEN_SI[:, 2])
    for pol in ["s", "p", "unpolarized"]:

        def r(d, a, i):
            stack = [1.0, n_si[i] + 1j * k_si[i], 1.52]
            th = math.radians(a)
            if pol == "unpolarized":
                return 0.5 * sum(tmm.coh_tmm(p, stack, [np.inf, d, np.inf], th, wl[i])["R"] for p in "sp")
            return tmm.coh_tmm(pol, stack, [np.inf, d, np.inf], th, wl[i])["R"]

        cols = np.array([[[r(d, a, i) for i in range(len(wl))] for d in thick] for a in angles])
        rng = np.random.default_rng(9)
        cube = np.repeat(cols[:, None, :, :], 6, axis=1) + rng.normal(0.0, 3e-4, (3, 6, 10, len(wl)))
        got = filmscope.estimate(
            cube, wl, angles, fwhm_nm=0.5, polarization=pol, film_index="si", thickness_range_nm=(20.0, 600.0)
        )
        assert np.isfinite(got.thickness_nm).all(), (pol, got.summary)
        err = np.abs(got.thickness_nm - thick[None, :])
        assert err.mean() < 1.0, (pol, err.mean())
