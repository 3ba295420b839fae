"""Type stubs of filmscope: thin-film index and thickness maps from hyperspectral angle sweeps."""

import os
from typing import Any, Dict, List, Mapping, Optional, Sequence, Union

import numpy as np
import numpy.typing as npt

__version__: str

PathLike = Union[str, os.PathLike[str]]
Material = Union[float, str, Mapping[str, Any], os.PathLike[str]]
"""A number, a library material name, a refractiveindex.info YAML path, or a dispersion dict."""

class FilmscopeError(ValueError):
    """A capture, scene, material or option filmscope cannot use; the message names it."""

class PixelFit:
    """The fit at one pixel (:meth:`EstimateResult.pixel_fit`)."""

    x: int
    y: int
    wavelengths_nm: npt.NDArray[np.float64]
    """Band centres, nm, ``(bands,)``."""
    angles_deg: npt.NDArray[np.float64]
    """Incidence angles, degrees, by increasing incidence, ``(angles,)``."""
    measured: npt.NDArray[np.float64]
    """Measured band reflectance, ``(angles, bands)`` (NaN where unusable)."""
    model: npt.NDArray[np.float64]
    """The model at the pixel's estimated thickness and the estimated index."""
    residual: npt.NDArray[np.float64]
    """``measured - model``."""
    thickness_nm: float
    """The pixel's estimated thickness (NaN: none)."""
    candidates: List[Dict[str, Any]]
    """Thickness candidates near the estimate (one per fringe order): ``thickness_nm``,
    ``rms`` (of the residual), ``model`` ``(angles, bands)``, best first."""

class EstimateResult:
    """What :func:`estimate` returns."""

    dispersion: Optional[Dict[str, Any]]
    """``summary["dispersion"]``: ``model``, its coefficients, ``n_550``, ``n_table``."""
    thickness_nm: npt.NDArray[np.float32]
    """Thickness per pixel, nm, ``(lines, samples)``; NaN where no reliable estimate."""
    confidence: npt.NDArray[np.float32]
    """Confidence of the thickness, 0..1."""
    sigma_nm: npt.NDArray[np.float32]
    """1-sigma thickness uncertainty, nm."""
    flags: npt.NDArray[np.uint16]
    """Pixel flag bits."""
    summary: Dict[str, Any]
    """``summary.json`` as a dict."""
    source: Optional[str]
    """The capture path, or None for an array input."""
    @property
    def n_550(self) -> float:
        """The film's index at 550 nm (NaN when no index was found)."""
    def n(self, wavelengths_nm: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """The estimated index at ``wavelengths_nm``."""
    def pixel_fit(self, x: int, y: int) -> PixelFit:
        """Measured spectra at every angle at pixel ``(x, y)`` (column, row) with the model
        and its residual, and the fits of the neighbouring fringe orders."""

def estimate(
    path_or_array: Union[PathLike, npt.ArrayLike],
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
) -> EstimateResult:
    """Estimates the film's index and thickness map from a capture folder or a
    ``(angles, lines, samples, bands)`` reflectance array (GIL released while it runs)."""

def index(n_model: Material, wavelengths_nm: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """The index of ``n_model`` at ``wavelengths_nm`` (same shape)."""

def reflectance(
    n_model: Material,
    d_nm: npt.ArrayLike,
    angles_deg: npt.ArrayLike,
    wavelengths_nm: npt.ArrayLike,
    fwhm_nm: float = 0.0,
    substrate: Material = 1.52,
    polarization: str = "unpolarized",
    ambient_index: float = 1.0,
    back_face: str = "none",
) -> npt.NDArray[np.float64]:
    """The forward model: shape ``broadcast(d_nm, angles_deg).shape + (len(wavelengths_nm),)``."""

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
    """Renders a scene: a capture written into ``out``, or the sweep and truth as arrays."""

def material_names() -> List[str]:
    """The built-in material library's names."""

def write_material(
    n_model: Material,
    path: PathLike,
    range_nm: Sequence[float] = (380.0, 780.0),
) -> None:
    """Writes ``n_model`` as a refractiveindex.info YAML entry (``.yml``/``.yaml``) or as a
    ``wavelength_nm,n`` CSV table (``.csv``)."""
