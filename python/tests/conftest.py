"""Shared helpers of the Python package's tests: a small scene and the CLI binary."""

import os
import shutil
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]


def small_scene(**over):
    """A small MgF2-like film on a constant substrate: 40 x 24 px, 4 angles, 2 nm bands."""
    scene = {
        "name": "py-small",
        "seed": 7,
        "polarization": "s",
        "film": {
            "index": 1.38,
            "thickness": {"base_nm": 420.0, "gradient_nm": [30.0, -10.0]},
        },
        "substrate": {"index": 1.65},
        "rig": {"angles_deg": [10.0, 25.0, 40.0, 55.0], "bands_nm": [420.0, 720.0, 2.0], "fwhm_nm": 4.0},
        "sensor": {"width": 40, "height": 24, "reflectance_noise_percent": 0.2},
        "search": {"index_range": [1.2, 3.0], "thickness_range_nm": [50.0, 2000.0]},
    }
    for k, v in over.items():
        scene[k] = v
    return scene


@pytest.fixture(scope="session")
def cli():
    """The `filmscope` command: $FILMSCOPE_BIN, the release build, or built now."""
    env = os.environ.get("FILMSCOPE_BIN")
    if env:
        return [env]
    built = REPO / "target" / "release" / "filmscope"
    if built.exists():
        return [str(built)]
    cargo = shutil.which("cargo")
    if cargo is None:
        pytest.skip("no filmscope binary and no cargo to build one")
    subprocess.run([cargo, "build", "--release", "--quiet", "--bin", "filmscope"], cwd=REPO, check=True)
    return [str(built)]
