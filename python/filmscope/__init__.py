"""filmscope from Python: thin-film refractive index and thickness maps from hyperspectral
angle sweeps.

- :func:`estimate` runs filmscope's estimator on an ENVI capture folder (as
  ``filmscope estimate`` reads it) or on a reflectance array, and returns the index model,
  the per-pixel maps as NumPy arrays and the summary.
- :func:`reflectance` is the forward model (a film on a substrate, Airy sum, optional
  Gaussian passband), vectorised over thickness and angle.
- :func:`simulate` renders a scene (TOML file or dict) as a capture on disk or as arrays.
- :func:`index` evaluates a material (number, dict, library name or refractiveindex.info
  YAML file) at wavelengths.

Errors are :class:`FilmscopeError` (a ``ValueError``) with one line naming the file, key or
value at fault. The estimator and the forward model release the GIL while they run.
"""

from __future__ import annotations

import json
import os
from typing import Any, Dict, Mapping, Optional, Sequence, Union

import numpy as np

from . import _native
from ._native import FilmscopeError, material_names

__all__ = [
    "EstimateResult",
    "FilmscopeError",
    "PixelFit",
    "estimate",
    "index",
    "material_names",
    "reflectance",
    "simulate",
    "write_material",
]

__version__ = _native.__version__

PathLike = Union[str, "os.PathLike[str]"]
Material = Union[float, str, Mapping[str, Any], "os.PathLike[str]"]


def _material_json(m: Any, what: str) -> str:
    """A material as the JSON text the native module reads (number, name/path, object)."""
    if isinstance(m, os.PathLike):
        m = os.fspath(m)
    if isinstance(m, (int, float, np.floating, np.integer)) and not isinstance(m, bool):
        return json.dumps(float(m))
    if isinstance(m, (str, Mapping)):
        try:
            return json.dumps(m if isinstance(m, str) else dict(m))
        except TypeError as e:
            raise FilmscopeError(f"{what}: {e}") from None
    raise FilmscopeError(
        f"{what}: expected a number, a material name or YAML path, or a dict, not {type(m).__name__}"
    )


class PixelFit:
    """The fit at one pixel (:meth:`EstimateResult.pixel_fit`).

    Attributes:
        x, y: the pixel (column, row).
        wavelengths_nm: band centres, ``(bands,)``.
        angles_deg: incidence angles, increasing, ``(angles,)``.
        measured: measured band reflectance, ``(angles, bands)`` (NaN where unusable), with
            the sample fit's reflectance terms and flare taken out as the maps' passes did.
        model: the model at the estimated thickness, same shape (NaN without one).
        residual: ``measured - model``.
        thickness_nm: the pixel's estimated thickness (NaN: none).
        candidates: local best fits over 2.5 interference orders either side, best first:
            dicts of ``thickness_nm``, ``rms`` and ``model`` ``(angles, bands)``.
    """

    def __init__(self, x, y, wavelengths_nm, angles_deg, measured, model, thickness_nm, candidates):
        self.x, self.y = x, y
        self.wavelengths_nm = wavelengths_nm
        self.angles_deg = angles_deg
        self.measured = measured
        self.model = model
        self.residual = measured - model
        self.thickness_nm = thickness_nm
        self.candidates = candidates

    def __repr__(self) -> str:
        c = ", ".join(f"{k['thickness_nm']:.1f} nm (rms {k['rms']:.4f})" for k in self.candidates)
        return f"PixelFit(({self.x}, {self.y}), d={self.thickness_nm:.2f} nm, candidates: {c})"


class EstimateResult:
    """What :func:`estimate` returns.

    Attributes:
        dispersion: the index model, ``summary["dispersion"]``: ``model`` (constant,
            cauchy or sellmeier), its coefficients, ``n_550`` and ``n_table``
            (``wavelength_nm`` and ``n`` lists over the bands); the index at 550 nm alone
            is :attr:`n_550` (``summary["refractive_index"]``).
        thickness_nm: film thickness per pixel, ``float32`` ``(lines, samples)``; NaN where
            no reliable estimate exists.
        confidence: confidence of the thickness, 0..1, ``float32``.
        sigma_nm: 1-sigma thickness uncertainty, nm, ``float32``.
        flags: pixel flags, ``uint16`` bits (``summary["flags"]`` counts each).
        summary: ``summary.json`` as a dict.
        source: the capture path, or None for an array input.
    """

    def __init__(self, raw: Dict[str, Any], source: Optional[str], pixel_input: Any = None):
        h, w = raw["height"], raw["width"]
        self.thickness_nm = np.frombuffer(raw["thickness_nm"], dtype=np.float32).reshape(h, w).copy()
        self.confidence = np.frombuffer(raw["confidence"], dtype=np.float32).reshape(h, w).copy()
        self.sigma_nm = np.frombuffer(raw["sigma_nm"], dtype=np.float32).reshape(h, w).copy()
        self.flags = np.frombuffer(raw["flags"], dtype=np.uint16).reshape(h, w).copy()
        self.summary: Dict[str, Any] = json.loads(raw["summary"])
        self.dispersion: Optional[Dict[str, Any]] = self.summary.get("dispersion")
        self.source = source
        self._pixel_input = pixel_input

    def pixel_fit(self, x: int, y: int) -> "PixelFit":
        """The fit at pixel ``(x, y)`` (column, row): the measured band reflectance at every
        angle, the model (the estimated index at the pixel's estimated thickness, on the
        sample's substrate, through each band's passband), the residual, and the
        neighbouring interference orders' fits, as ``filmscope report RUN --pixel X,Y``
        shows them."""
        h, w = self.thickness_nm.shape
        if not (0 <= int(x) < w and 0 <= int(y) < h):
            raise FilmscopeError(f"pixel ({x}, {y}) is outside the {w}x{h} maps")
        x, y = int(x), int(y)
        kind = self._pixel_input[0] if self._pixel_input else None
        if kind == "capture":
            sp = _native.capture_spectra(self._pixel_input[1], x, y)
            angles = list(sp["angles_deg"])
            wl, fw = list(sp["wavelengths_nm"]), list(sp["fwhm_nm"])
            measured = np.frombuffer(sp["measured"], dtype=np.float64).reshape(len(angles), len(wl))
            substrate, ambient, pol = sp["substrate"], sp["ambient_index"], sp["polarization"]
            back = sp["back_face"]
        elif kind == "array":
            _, cube, wl, angles, fw, substrate, ambient, pol, back = self._pixel_input
            # An array streams its angles increasing: the sample terms' order.
            order = np.argsort(angles, kind="stable")
            angles = [angles[i] for i in order]
            measured = cube[order, y, x, :].astype(np.float64)
        else:
            raise FilmscopeError("pixel_fit: this result keeps no input to fit")
        if self.dispersion is None:
            raise FilmscopeError("pixel_fit: the estimate found no index")
        d = float(self.thickness_nm[y, x])
        med = self.summary.get("thickness_nm", {}).get("median")
        raw = _native.pixel_fit(
            json.dumps(self.dispersion), substrate, float(ambient), pol, back,
            [float(v) for v in wl], [float(v) for v in fw], [float(a) for a in angles],
            np.ascontiguousarray(measured, dtype=np.float64).tobytes(),
            d, float("nan") if med is None else float(med), x, y,
            json.dumps(self.summary.get("index_model_choice", {}).get("nuisance_terms")),
        )
        shape = measured.shape
        return PixelFit(x, y, np.asarray(wl, dtype=np.float64),
                        np.asarray(raw["angles_deg"], dtype=np.float64),
                        np.frombuffer(raw["measured"], dtype=np.float64).reshape(shape).copy(),
                        np.frombuffer(raw["model"], dtype=np.float64).reshape(shape).copy(), d,
                        [{"thickness_nm": c["thickness_nm"], "rms": c["rms"],
                          "model": np.frombuffer(c["model"], dtype=np.float64).reshape(shape).copy()}
                         for c in raw["candidates"]])

    @property
    def n_550(self) -> float:
        """The film's index at 550 nm (NaN when no index was found)."""
        v = self.summary.get("refractive_index")
        return float("nan") if v is None else float(v)

    def n(self, wavelengths_nm: Any) -> np.ndarray:
        """The estimated index at ``wavelengths_nm`` (array-like, nm)."""
        wl = np.asarray(wavelengths_nm, dtype=np.float64)
        if self.dispersion is None:
            return np.full(wl.shape, np.nan)
        return index(self.dispersion, wl)

    def __repr__(self) -> str:
        h, w = self.thickness_nm.shape
        med = self.summary.get("thickness_nm", {}).get("median")
        return (
            f"EstimateResult(n_550={self.n_550:.4f}, model={self.summary.get('index_model')!r}, "
            f"{w}x{h} px, median thickness {med} nm, valid {self.summary.get('valid_fraction', 0):.3f})"
        )


def estimate(
    path_or_array: Any,
    wavelengths_nm: Optional[Sequence[float]] = None,
    angles_deg: Optional[Sequence[float]] = None,
    *,
    fwhm_nm: Union[None, float, Sequence[float]] = None,
    substrate: Material = 1.52,
    ambient_index: float = 1.0,
    polarization: str = "s",
    back_face: str = "none",
    index_range: Optional[Sequence[float]] = None,
    thickness_range_nm: Optional[Sequence[float]] = None,
    out: Optional[PathLike] = None,
    method: str = "filmscope",
    workers: int = 2,
    channel_capacity: int = 64,
    index_pixels: Optional[int] = None,
    sample_sites: Optional[int] = None,
    one_pass: bool = False,
    field: str = "auto",
    film_index: Optional[Material] = None,
    model_error: Optional[float] = None,
    rig_tolerance: Optional[float] = None,
) -> EstimateResult:
    """Estimates the film's refractive index and a per-pixel thickness map.

    Args:
        path_or_array: an ENVI capture folder (or its ``capture.toml``), read exactly as
            ``filmscope estimate`` reads it (the maps are the CLI's, bit for bit); or a
            float array ``(angles, lines, samples, bands)`` of calibrated reflectance.
        wavelengths_nm: band centres, nm (array input only; one per band).
        angles_deg: incidence angles, degrees (array input only; one per angle, any order).
        fwhm_nm: band widths, nm, one number or one per band (array input; default: the
            band spacing).
        substrate: the substrate (array input): a number, a library material name, a
            refractiveindex.info YAML path or a dispersion dict. A capture gives its own.
        ambient_index: index of the medium the light comes from (array input).
        polarization: ``"s"``, ``"p"`` or ``"unpolarized"`` (array input).
        back_face: the substrate's back face (array input): ``"none"`` (index-matched,
            black or absent) or ``"bare"`` (a clear substrate whose far side reflects, added
            incoherently), as ``sample.back_face`` in a capture.
        index_range: ``[low, high]`` film index search range (array input).
        thickness_range_nm: ``[low, high]`` thickness search range, nm (array input; default: 20 nm to the thickest film the bands resolve).
        out: a folder to write the maps, previews and ``summary.json`` into, as the CLI's
            ``--out`` (default: nothing is kept on disk).
        method: ``"filmscope"`` (default), ``"paper"`` or ``"brute"``.
        workers, channel_capacity, index_pixels, sample_sites, one_pass, field: as the
            CLI's options of the same names.
        film_index: the film's index known beforehand (any form :func:`index` takes), held
            instead of fitted, as ``filmscope estimate --film-index`` (a model the estimator
            cannot hold, such as a two- or three-term Sellmeier, as its least-squares
            three-term Cauchy over the bands).
        model_error: the model error the index fit tolerates, RMS reflectance, as
            ``estimate --model-error`` (default: the capture's ``[fit] model_error``, else
            0.003; 0 judges the fit against the noise alone).
        rig_tolerance: how far the index sigma carries the nuisance terms a real rig
            keeps, as a multiple of the typical rig's, as ``estimate --rig-tolerance``
            (default: the capture's ``[fit] rig_tolerance``, else 1; 0: the statistical
            sigma under the terms the fit took). Changes the sigmas only.

    Returns:
        An :class:`EstimateResult`.

    Raises:
        FilmscopeError: a capture, array or option that cannot be used (one line saying
            which and why).
    """
    n = _native
    ip = n.DEFAULT_INDEX_PIXELS if index_pixels is None else int(index_pixels)
    ss = n.DEFAULT_SAMPLE_SITES if sample_sites is None else int(sample_sites)
    out_s = None if out is None else os.fspath(out)
    fi = None if film_index is None else _material_json(film_index, "film_index")
    me = None if model_error is None else float(model_error)
    rt = None if rig_tolerance is None else float(rig_tolerance)
    if isinstance(path_or_array, (str, os.PathLike)):
        path = os.fspath(path_or_array)
        raw = n.estimate_capture(
            path, out_s, method, int(workers), int(channel_capacity), ip, ss, bool(one_pass), field, fi, me, rt
        )
        return EstimateResult(raw, path, ("capture", path))
    arr = np.asarray(path_or_array)
    if arr.ndim != 4:
        raise FilmscopeError(
            f"array: expected 4 dimensions (angles, lines, samples, bands), got shape {arr.shape}"
        )
    if not np.issubdtype(arr.dtype, np.number):
        raise FilmscopeError(f"array: expected numbers, got dtype {arr.dtype}")
    if wavelengths_nm is None or angles_deg is None:
        raise FilmscopeError("array input needs wavelengths_nm and angles_deg")
    cube = np.ascontiguousarray(arr, dtype=np.float32)
    wl = [float(x) for x in np.asarray(wavelengths_nm, dtype=np.float64).ravel()]
    ang = [float(x) for x in np.asarray(angles_deg, dtype=np.float64).ravel()]
    fw: Optional[list] = None
    if fwhm_nm is not None:
        f = np.asarray(fwhm_nm, dtype=np.float64)
        fw = [float(x) for x in (np.full(len(wl), float(f)) if f.ndim == 0 else f.ravel())]
    sub_json = _material_json(substrate, "substrate")
    ir = None if index_range is None else [float(x) for x in index_range]
    tr = None if thickness_range_nm is None else [float(x) for x in thickness_range_nm]
    raw = n.estimate_array(
        cube.tobytes(),
        list(cube.shape),
        wl,
        ang,
        fw,
        float(ambient_index),
        sub_json,
        polarization,
        back_face,
        ir,
        tr,
        out_s,
        method,
        int(workers),
        int(channel_capacity),
        ip,
        ss,
        bool(one_pass),
        fi,
        me,
        rt,
    )
    fw_list = fw if fw is not None else _band_spacing(wl)
    return EstimateResult(raw, None, ("array", cube, wl, ang, fw_list, sub_json, float(ambient_index), polarization, back_face))


def _band_spacing(wl: Sequence[float]) -> list:
    """Each band's width when none is given: the spacing to its neighbour (as the estimator takes it)."""
    out = []
    for i in range(len(wl)):
        j = i + 1 if i + 1 < len(wl) else i - 1
        out.append(abs(wl[j] - wl[i]) if len(wl) > 1 else 0.0)
    return out


def index(n_model: Material, wavelengths_nm: Any) -> np.ndarray:
    """The index of ``n_model`` at ``wavelengths_nm`` (array-like, nm), same shape.

    ``n_model`` is a number, a library material name (:func:`material_names`), a
    refractiveindex.info YAML file path, or a dict such as ``summary["dispersion"]``
    (``{"model": "cauchy", "a": ..., "b_um2": ..., "c_um4": ...}``, ``{"model":
    "sellmeier", "a": ..., "b": [...], "c_um": [...]}``, ``{"model": "constant", "n": ...}``).
    """
    wl = np.asarray(wavelengths_nm, dtype=np.float64)
    vals = _native.index_at(_material_json(n_model, "n_model"), [float(x) for x in wl.ravel()])
    return np.asarray(vals, dtype=np.float64).reshape(wl.shape)


def write_material(n_model: Material, path: PathLike, range_nm: Sequence[float] = (380.0, 780.0)) -> None:
    """Writes ``n_model`` (any form :func:`index` takes) as a refractiveindex.info YAML
    entry (a ``.yml``/``.yaml`` path: formula 1 for Sellmeier, formula 5 for Cauchy,
    ``tabulated n`` for a constant) valid over ``range_nm``, or as a ``wavelength_nm,n``
    CSV table at 1 nm steps over it (a ``.csv`` path)."""
    lo, hi = (float(x) for x in range_nm)
    _native.write_material(_material_json(n_model, "n_model"), os.fspath(path), lo, hi)


def reflectance(
    n_model: Material,
    d_nm: Any,
    angles_deg: Any,
    wavelengths_nm: Any,
    fwhm_nm: float = 0.0,
    substrate: Material = 1.52,
    polarization: str = "unpolarized",
    ambient_index: float = 1.0,
    back_face: str = "none",
) -> np.ndarray:
    """Reflectance of a film on a substrate: filmscope's forward model.

    ``d_nm`` and ``angles_deg`` broadcast against each other (NumPy rules); the result has
    their broadcast shape plus a last axis over ``wavelengths_nm`` (a 1-D array, nm).

    Args:
        n_model: the film's index: a number, a dict (``summary["dispersion"]``), a library
            material name or a refractiveindex.info YAML path.
        d_nm: film thickness, nm (0: the bare substrate).
        angles_deg: incidence angle in the ambient medium, degrees, in [0, 90).
        wavelengths_nm: vacuum wavelengths, nm.
        fwhm_nm: Gaussian passband FWHM, nm (0: monochromatic).
        substrate: the substrate's index, in any form ``n_model`` takes.
        polarization: ``"s"``, ``"p"`` or ``"unpolarized"`` (the mean of the two).
        ambient_index: index of the incidence medium.
        back_face: ``"none"`` or ``"bare"``: the substrate's far side reflecting too (a clear
            substrate in the ambient medium, its return added incoherently).

    Returns:
        ``float64`` array of shape ``broadcast(d_nm, angles_deg).shape + (len(wavelengths_nm),)``.
    """
    d, a = np.broadcast_arrays(np.asarray(d_nm, dtype=np.float64), np.asarray(angles_deg, dtype=np.float64))
    wl = np.atleast_1d(np.asarray(wavelengths_nm, dtype=np.float64))
    if wl.ndim != 1:
        raise FilmscopeError(f"wavelengths_nm: expected a 1-D array, got shape {wl.shape}")
    raw = _native.reflectance(
        _material_json(n_model, "n_model"),
        [float(x) for x in d.ravel()],
        [float(x) for x in a.ravel()],
        [float(x) for x in wl],
        float(fwhm_nm),
        _material_json(substrate, "substrate"),
        float(ambient_index),
        polarization,
        back_face,
    )
    return np.frombuffer(raw, dtype=np.float64).reshape(d.shape + (wl.size,)).copy()


def simulate(
    scene: Union[PathLike, Mapping[str, Any]],
    out: Optional[PathLike] = None,
    *,
    noise_free: bool = False,
    float_reflectance: bool = False,
    interleave: str = "bil",
    byte_order: str = "little",
    seed: Optional[int] = None,
) -> Dict[str, Any]:
    """Renders a scene with filmscope's software camera.

    Args:
        scene: a scene TOML file (as ``config/scenes/*.toml``) or the same content as a dict.
        out: a folder to write the capture into (``capture.toml``, ENVI cubes, ``truth.json``
            and ``truth/thickness_nm``), as ``filmscope simulate --out``. Without it the
            sweep is returned as arrays.
        noise_free: float reflectance without noise, defects or vignetting.
        float_reflectance: (with ``out``) float reflectance, noise and all, instead of raw
            counts with white and dark references.
        interleave, byte_order: the cubes' layout (with ``out``).
        seed: replaces the scene's ``seed`` (thickness bumps and noise).

    Returns:
        With ``out``: ``{"name", "capture"}`` (the capture.toml path). Without: ``{"name",
        "reflectance"`` (``float32 (angles, lines, samples, bands)``: calibrated reflectance,
        noisy unless ``noise_free``), ``"wavelengths_nm", "angles_deg", "fwhm_nm",
        "thickness_nm"`` (the true map, ``(lines, samples)``), ``"film", "substrate"``
        (dispersion dicts), ``"ambient_index", "polarization"}``.
    """
    path = text = None
    if isinstance(scene, Mapping):
        text = _toml_text(scene)
    else:
        path = os.fspath(scene)
    raw = _native.simulate(
        path,
        text,
        None if out is None else os.fspath(out),
        bool(noise_free),
        interleave,
        byte_order,
        bool(float_reflectance),
        None if seed is None else int(seed),
    )
    if "reflectance" not in raw:
        return dict(raw)
    na, h, w, nb = raw["shape"]
    res = dict(raw)
    res["reflectance"] = np.frombuffer(raw["reflectance"], dtype=np.float32).reshape(na, h, w, nb).copy()
    res["thickness_nm"] = np.frombuffer(raw["thickness_nm"], dtype=np.float32).reshape(h, w).copy()
    res["wavelengths_nm"] = np.asarray(raw["wavelengths_nm"])
    res["angles_deg"] = np.asarray(raw["angles_deg"])
    res["film"] = json.loads(raw["film"])
    res["substrate"] = json.loads(raw["substrate"])
    del res["shape"]
    return res


def _toml_text(table: Mapping[str, Any]) -> str:
    """A scene dict as TOML text (tables, arrays, inline tables in arrays, scalars)."""

    def value(v: Any, where: str) -> str:
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, (int, np.integer)):
            return str(int(v))
        if isinstance(v, (float, np.floating)):
            return repr(float(v))
        if isinstance(v, str):
            return json.dumps(v)
        if isinstance(v, Mapping):
            return "{ " + ", ".join(f"{k} = {value(x, where + '.' + k)}" for k, x in v.items()) + " }"
        if isinstance(v, (list, tuple, np.ndarray)):
            return "[" + ", ".join(value(x, where) for x in v) + "]"
        raise FilmscopeError(f"scene: {where}: cannot write a {type(v).__name__} as TOML")

    lines = []
    for k, v in table.items():
        if not isinstance(v, Mapping):
            lines.append(f"{k} = {value(v, k)}")

    def section(prefix: str, t: Mapping[str, Any]) -> None:
        lines.append(f"[{prefix}]")
        subs = []
        for k, v in t.items():
            if isinstance(v, Mapping):
                subs.append((k, v))
            else:
                lines.append(f"{k} = {value(v, prefix + '.' + k)}")
        for k, v in subs:
            section(f"{prefix}.{k}", v)

    for k, v in table.items():
        if isinstance(v, Mapping):
            section(k, v)
    return "\n".join(lines) + "\n"
