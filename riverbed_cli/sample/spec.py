"""Block sizes (:class:`SizeSpec`, :data:`SIZES`), the constants every block shares (CRS, origin, heading, sun,
DSM nodata, file list, stages) and the along-track positions of the exposures."""

from dataclasses import dataclass


CRS = "EPSG:32632"
#: Local origin (world coordinates of local 0, 0, 0) of every generated block: UTM 32N, northern Italy.
ORIGIN = (501230.0, 5002470.0, 200.0)
#: Flight direction, degrees clockwise from north (the rectified images' x axis points this way).
HEADING = 70.0
#: Sun position: azimuth (degrees clockwise from north) and elevation (degrees).
SUN_AZIMUTH, SUN_ELEVATION = 155.0, 38.0
#: DSM nodata value.
NODATA = -9999.0
#: Stages of :func:`make_block` and :func:`generate_block`, in order (for progress reporting).
STAGES = ("scene", "render", "ground_truth", "lidar", "write")
#: Files of a block, in the order they are written.
FILES = ("left.png", "right.png", "pair.yaml", "lidar.laz", "lidar_earlier.laz", "gt_disparity.tif", "gt_dsm.tif",
         "scene.json", "MANIFEST.md", "raw")
#: Raw (unrectified) frames of the pair written to ``raw/`` (``frameK.png`` and its orientation
#: ``frameK.yaml``).
RAW_FRAMES = (0, 1)
#: Pixel size (mm) stated in the raw frames' orientation files (focal length 12 mm small, 16 mm full).
RAW_PIXEL_SIZE_MM = 0.004


@dataclass(frozen=True)
class SizeSpec:
    """Parameters of one block size.

    ``raw_size`` and ``rect_size`` are ``(width, height)`` in pixels with x along the flight line; ``cell`` is the
    spacing of the surface's nodes (m); LiDAR values are the scanner's height above ground (m), half field of view
    (deg), speed (m/s) and pulses per m^2 of one strip.
    """

    name: str
    gsd: float
    flying_height: float
    raw_size: tuple
    overlap: float
    rect_size: tuple
    cell: float
    exposures: int = 3
    supersample: int = 2
    lidar_agl: float = 500.0
    lidar_half_fov: float = 10.0
    lidar_speed: float = 60.0
    lidar_density: float = 0.5

    @property
    def focal(self):
        return self.flying_height / self.gsd

    @property
    def baseline(self):
        return (1.0 - self.overlap) * self.raw_size[0] * self.gsd


SIZES = {
    "small": SizeSpec("small", gsd=0.2, flying_height=600.0, raw_size=(1200, 800), overlap=0.6, rect_size=(720, 540),
                      cell=0.2 / 3),
    "full": SizeSpec("full", gsd=0.2, flying_height=800.0, raw_size=(3400, 2268), overlap=0.6,
                     rect_size=(2000, 1500), cell=0.1, lidar_half_fov=15.0),
}


def exposure_us(spec):
    """Along-track (u) positions of the exposures: the rectified pair (exposures 0 and 1) straddles u = 0."""
    B = spec.baseline
    return [(k - 0.5) * B for k in range(spec.exposures)]
