import os
from pathlib import Path

import numpy as np
import pytest

from riverbed_cli.io.disparity import read_disparity
from riverbed_cli.io.images import read_image

DATA = Path(__file__).parent / "data"


@pytest.fixture(scope="session")
def cones():
    """Middlebury 2003 Cones, quarter size (450x375): left, right, GT (d = value / 4, NaN unknown)."""
    base = DATA / "cones"
    return read_image(base / "im2.png"), read_image(base / "im6.png"), read_disparity(base / "disp2.png", scale=4)


@pytest.fixture(scope="session")
def shared_data():
    """The shared real-data folder (KITTI etc., not in the repository), from RIVERBED_DATA."""
    path = os.environ.get("RIVERBED_DATA")
    if not path or not Path(path).is_dir():
        pytest.fail("RIVERBED_DATA must name the shared data folder (.ci/run sets it to ../shared/data)")
    return Path(path)


def rng():
    return np.random.default_rng(12345)
