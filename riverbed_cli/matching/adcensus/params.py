"""AD-Census settings (:class:`ADCensusParams`) and where guidance may act on the volume (:data:`GUIDE_STAGES`)."""

from dataclasses import dataclass

GUIDE_STAGES = ("aggregated", "initial")  # guidance on the aggregated volume (before SO) or on the raw cost


@dataclass(frozen=True)
class ADCensusParams:
    """AD-Census settings; defaults are the paper's (Mei et al. 2011, Table 1) where it gives them."""

    lambda_ad: float = 10.0  # robust-function scale of the AD term (grey levels 0..255, mean over channels)
    lambda_census: float = 30.0  # robust-function scale of the census term (Hamming distance, bits)
    scale: int = 256  # fixed-point cost units per 1.0 of the paper's cost (raw costs then lie in [0, 512])
    outside: float = 1.0  # cost (paper units) where the match leaves the right image (measured: 0.5 is too low)
    arm_l1: int = 34  # L1: arm length limit (px); arms are at most L1 - 1 long
    arm_l2: int = 17  # L2: arm length (px) beyond which the stricter colour threshold arm_tau2 applies
    arm_tau1: int = 20  # tau1: colour difference (0..255, max over channels) an arm pixel must stay below
    arm_tau2: int = 6  # tau2: the (stricter) colour difference an arm pixel must stay below beyond L2
    iterations: int = 4  # cross-aggregation passes (odd ones horizontal-first, even ones vertical-first)
    pi1: float = 1.0  # scanline-optimisation penalty P1 (paper cost units) of a 1 px disparity change
    pi2: float = 3.0  # penalty P2 (paper cost units) of a larger jump; both divided by 4 or 10 at colour edges
    tau_so: int = 15  # colour difference (0..255) along a path from which the penalties are reduced
    lr_threshold: int = 1  # left-right check: largest left / right disparity difference (px) of a reliable pixel
    vote_iterations: int = 5  # region-voting iterations (0: no voting)
    vote_ts: int = 20  # region voting: an outlier needs more than this many reliable pixels voting
    vote_th: float = 0.4  # region voting: and a winner with more than this share of the votes
    interpolate: bool = True  # proper interpolation of the outliers left after voting (16 directions)
    discontinuity: bool = True  # depth-discontinuity adjustment (disparity edges take a cheaper neighbour's)
    edge_threshold: float = 5.0  # Sobel |gx| + |gy| of the disparity map above which a pixel is a disparity edge
    guide_stage: str = "aggregated"  # where guidance modulates the volume: "aggregated" (before SO) or "initial"
