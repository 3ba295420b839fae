"""filmscope.reflectance against the tmm package (transfer matrices, independent code)."""

import math

import numpy as np
import pytest

import filmscope

tmm = pytest.importorskip("tmm")

WL = np.array([400.0, 455.5, 532.0, 633.0, 780.0])
ANGLES = np.array([0.0, 15.0, 35.0, 55.0, 70.0])
THICK = np.array([0.0, 85.0, 410.0, 1333.0])


def tmm_r(pol, n_film, n_sub, d, angle, wl):
    if pol == "unpolarized":
        return 0.5 * (tmm_r("s", n_film, n_sub, d, angle, wl) + tmm_r("p", n_film, n_sub, d, angle, wl))
    return tmm.coh_tmm(pol, [1.0, n_film, n_sub], [np.inf, d, np.inf], math.radians(angle), wl)["R"]


@pytest.mark.parametrize("pol", ["s", "p", "unpolarized"])
@pytest.mark.parametrize("n_film,n_sub", [(1.38, 1.52), (2.35, 1.65), (1.46, 1.46)])
def test_matches_tmm_constant_indices(pol, n_film, n_sub):
    got = filmscope.reflectance(n_film, THICK[:, None], ANGLES[None, :], WL, substrate=n_sub, polarization=pol)
    assert got.shape == (len(THICK), len(ANGLES), len(WL))
    want = np.array(
        [[[tmm_r(pol, n_film, n_sub, d, a, l) for l in WL] for a in ANGLES] for d in THICK]
    )
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)


@pytest.mark.parametrize("pol", ["s", "p", "unpolarized"])
def test_matches_tmm_dispersive_film_and_substrate(pol):
    # ZnS (library Sellmeier form of Debenham's formula) on BK7 (SCHOTT, formula 2).
    bk7 = {"model": "sellmeier", "b": [1.03961212, 0.231792344, 1.01046945],
           "c_um": [math.sqrt(0.00600069867), math.sqrt(0.0200179144), math.sqrt(103.560653)]}
    got = filmscope.reflectance("zns", 250.0, ANGLES, WL, substrate=bk7, polarization=pol)
    n_film = filmscope.index("zns", WL)
    n_sub = filmscope.index(bk7, WL)
    want = np.array([[tmm_r(pol, n_film[i], n_sub[i], 250.0, a, l) for i, l in enumerate(WL)] for a in ANGLES])
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)


def tmm_bare(pol, n_film, n_sub, d, angle, wl):
    """A 1 mm substrate, incoherent, with air behind: its bare back face's return."""
    if pol == "unpolarized":
        return 0.5 * (tmm_bare("s", n_film, n_sub, d, angle, wl) + tmm_bare("p", n_film, n_sub, d, angle, wl))
    return tmm.inc_tmm(pol, [1.0, n_film, n_sub, 1.0], [np.inf, d, 1e6, np.inf],
                       ["i", "c", "i", "i"], math.radians(angle), wl)["R"]


@pytest.mark.parametrize("pol", ["s", "p", "unpolarized"])
@pytest.mark.parametrize("n_film,n_sub", [(1.38, 1.52), (2.35, 1.65)])
def test_a_bare_back_face_matches_tmm_incoherent_substrate(pol, n_film, n_sub):
    got = filmscope.reflectance(n_film, THICK[:, None], ANGLES[None, :], WL, substrate=n_sub,
                                polarization=pol, back_face="bare")
    want = np.array(
        [[[tmm_bare(pol, n_film, n_sub, d, a, l) for l in WL] for a in ANGLES] for d in THICK]
    )
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)
    with pytest.raises(filmscope.FilmscopeError, match="back_face"):
        filmscope.reflectance(n_film, 100.0, 10.0, WL, back_face="frosted")


def test_broadcast_and_passband():
    r0 = filmscope.reflectance(1.38, [300.0, 310.0], 30.0, WL)
    assert r0.shape == (2, len(WL))
    # A passband averages the fringes: the average of the monochromatic model over the
    # band's nodes lies between its extremes and differs from the centre value.
    wide = filmscope.reflectance(1.38, 1500.0, 30.0, [550.0], fwhm_nm=10.0)[0]
    fine = filmscope.reflectance(1.38, 1500.0, 30.0, np.linspace(535.0, 565.0, 301))
    assert fine.min() <= wide <= fine.max()
    assert abs(wide - filmscope.reflectance(1.38, 1500.0, 30.0, [550.0])[0]) > 1e-4


def test_bad_inputs_raise_one_line():
    with pytest.raises(filmscope.FilmscopeError, match="unobtainium"):
        filmscope.reflectance("unobtainium", 100.0, 10.0, WL)
    with pytest.raises(filmscope.FilmscopeError, match="polarization"):
        filmscope.reflectance(1.4, 100.0, 10.0, WL, polarization="circular")
    with pytest.raises(filmscope.FilmscopeError, match="angles_deg"):
        filmscope.reflectance(1.4, 100.0, 95.0, WL)
    with pytest.raises(ValueError, match="b_um2"):
        filmscope.reflectance({"model": "cauchy", "a": 1.4}, 100.0, 10.0, WL)


# Crystalline silicon at 300 K (Green 2008, Table 1): wavelength nm, n, k at table rows.
SILICON_ROWS = [(400, 5.613, 0.296), (450, 4.691, 0.086302), (500, 4.294, 0.044165),
                (550, 4.077, 0.027968), (600, 3.940, 0.019934), (650, 3.844, 0.014431),
                (700, 3.772, 0.010528)]


@pytest.mark.parametrize("pol", ["s", "p", "unpolarized"])
def test_silicon_matches_tmm_with_its_complex_index(pol):
    """substrate="si" is silicon's n + i k (tmm's sign: k > 0 absorbs), at the table's rows."""
    tmm = pytest.importorskip("tmm")
    wl = np.array([r[0] for r in SILICON_ROWS], dtype=float)
    got = filmscope.reflectance(1.46, THICK[:, None], ANGLES[None, :], wl, substrate="si",
                                polarization=pol)

    def r(p, d, a, i):
        _, n, k = SILICON_ROWS[i]
        return tmm.coh_tmm(p, [1.0, 1.46, n + 1j * k], [np.inf, d, np.inf],
                           math.radians(a), wl[i])["R"]

    def one(d, a, i):
        return 0.5 * (r("s", d, a, i) + r("p", d, a, i)) if pol == "unpolarized" else r(pol, d, a, i)

    want = np.array([[[one(d, a, i) for i in range(len(wl))] for a in ANGLES] for d in THICK])
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)
