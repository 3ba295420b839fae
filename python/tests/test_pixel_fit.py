"""The fit at one pixel: from Python and from `filmscope report RUN --pixel X,Y`."""

import subprocess
from pathlib import Path

import numpy as np
import pytest

import filmscope
from conftest import small_scene


def test_capture_pixel_fit_matches_the_cli(tmp_path, cli):
    cap = filmscope.simulate(small_scene(), tmp_path / "cap", seed=9)
    r = filmscope.estimate(Path(cap["capture"]).parent, out=tmp_path / "est")
    x, y = 7, 5
    fit = r.pixel_fit(x, y)
    assert fit.measured.shape == fit.model.shape == (4, 151)
    assert list(fit.angles_deg) == [10.0, 25.0, 40.0, 55.0]
    assert fit.thickness_nm == float(r.thickness_nm[y, x])
    # Residual at the noise level (0.2 % of white), the estimate the best candidate and
    # the neighbouring orders clearly worse.
    rms = float(np.sqrt(np.nanmean(fit.residual**2)))
    assert rms < 0.004, rms
    best = fit.candidates[0]
    assert abs(best["thickness_nm"] - fit.thickness_nm) < 1.0
    assert len(fit.candidates) >= 2 and fit.candidates[1]["rms"] > 2 * best["rms"]
    out = subprocess.run(cli + ["report", str(tmp_path / "est"), "--pixel", f"{x},{y}"],
                         check=True, capture_output=True, text=True).stdout
    assert "(the estimate)" in out
    rows = np.loadtxt(tmp_path / "est" / f"pixel-{x}-{y}.csv", delimiter=",", skiprows=1)
    assert rows.shape == (4 * 151, 5)
    np.testing.assert_array_equal(rows[:, 2].reshape(4, 151), fit.measured)
    np.testing.assert_allclose(rows[:, 3].reshape(4, 151), fit.model, rtol=0, atol=1e-12)
    assert (tmp_path / "est" / f"pixel-{x}-{y}.png").stat().st_size > 1000


def test_array_pixel_fit_on_data_without_noise():
    # No noise but the ADC's rounding (the estimator's noise gate needs some noise).
    scene = small_scene(sensor={"width": 40, "height": 24, "reflectance_noise_percent": 0.0})
    sim = filmscope.simulate(scene, seed=9)
    r = filmscope.estimate(sim["reflectance"], sim["wavelengths_nm"], sim["angles_deg"],
                           fwhm_nm=sim["fwhm_nm"], substrate=sim["substrate"])
    fit = r.pixel_fit(20, 12)
    truth = float(sim["thickness_nm"][12, 20])
    assert abs(fit.candidates[0]["thickness_nm"] - truth) < 0.5
    assert np.nanmax(np.abs(fit.residual)) < 2e-3
    with pytest.raises(filmscope.FilmscopeError, match="outside"):
        r.pixel_fit(40, 0)
