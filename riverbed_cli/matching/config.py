"""The matching settings: one table, from which the command line, the block manifest and :class:`MatchConfig` come.

:data:`MATCH_SETTINGS` lists every setting a ``riverbed match`` user can set: its flat name (``--name`` on the
command line, ``name`` in a block manifest's ``defaults:`` or per pair), default, validator, help, and the part of
:class:`MatchConfig` it fills (``group.field``). ``riverbed match``'s options, the manifest's keys and their
validation messages are generated from it, so a new setting is one new row (and a field of its group).

:class:`MatchConfig` is nested and frozen: the matcher and guide names, the settings every matcher shares (census
window, sub-pixel fit, median), and one frozen group per matcher or guide (:class:`SGMConfig`,
:class:`GuidanceConfig` for Gauss and riverbed, :class:`DiffusionConfig`, :class:`PlusConfig`,
:class:`ADCensusConfig`). ``MatchConfig().replace(guide="gauss", p2=150)`` takes flat names.

This module imports no Numba kernel (``riverbed match --help`` reads it).
"""

import math
from dataclasses import dataclass, field, fields, replace

from ..errors import RiverbedError
from ..settings import (
    MAX_PIXELS,
    Setting,
    SettingError,
    auto_or,
    boolean,
    census_window,
    choice,
    integer,
    number,
    odd_window_upto,
    show,
)

#: Matchers and guides by name; each has an implementation registered under that name (``matching/matchers/``,
#: ``matching/guides/``; :mod:`.registry` checks the two lists agree).
MATCHER_NAMES = ("sgm", "adcensus")
GUIDE_NAMES = ("none", "gauss", "riverbed", "diffusion", "riverbed+")
FORMS = ("additive", "product")
CONFIDENCES = ("lr", "none")
GUIDE_STAGES = ("aggregated", "initial")
RANGES = ("auto", "tube", "tile", "full")
#: the LiDAR check's modes (matching/lidar_check.py)
LIDAR_CHECKS = ("auto", "off")
#: what pixels with no LiDAR within a tube's reach search: the nominal range, or a coarse stereo match's range
TUBE_HOLES = ("full", "coarse")
#: the fusion's interpolations of the LiDAR (``fusion_lidar``): auto, local planes, the Delaunay triangulation
LIDAR_KINDS = ("auto", "planes", "linear")
#: fusions of the matched disparity with the LiDAR (``matching/fusions/``; the arithmetic in ``matching/fusion.py``);
#: ``auto`` is not one of them: it picks one per match (``pipeline.resolve_fusion``)
FUSION_NAMES = ("none", "confidence")
FUSION_CHOICES = ("auto",) + FUSION_NAMES

#: largest riverbed window side (px): the auto window lies in [5, 25]; a window of 100001 px ran out of memory
MAX_WINDOW = 101

# Defaults of the run settings (tiling, range, input size), shared by match_tiled and the command line.
TILE_DEFAULT = "auto"
OVERLAP_DEFAULT = 128


@dataclass(frozen=True)
class SGMConfig:
    """Census + SGM matcher settings (penalties in Hamming units)."""

    paths: int = 8  # SGM path directions: 4, 8 or 16
    p1: int = 10  # penalty of a 1 px disparity change
    p2: int = 120  # penalty of a larger change
    lr_check: bool = False  # invalidate pixels failing the left-right consistency check
    lr_threshold: int = 1  # px
    outside_cost: object = "auto"  # cost where the match leaves the right image; auto = a quarter of the bits
    cost_scale: int = 4  # guided costs are kept in uint16 at this resolution (1/4 of a Hamming unit)


@dataclass(frozen=True)
class GuidanceConfig:
    """Gauss and riverbed guidance (the paper's k = 10, c = 1, sigma = 8, gamma = 0.3)."""

    k: float = 10.0  # height of the Gaussian walls (times the wall scale)
    c: float = 1.0  # width of the walls (disparity px)
    form: str = "additive"  # additive or product walls (docs/method.md)
    wall_scale: object = "auto"  # F_bar of the additive walls; auto = half the largest cost of a random mismatch
    window: object = "auto"  # riverbed window side s (odd px) or "auto"
    window_target: float = 4.0  # auto window: smallest odd s with s * s * p >= window_target (docs/method.md)
    sigma_xy: float = 8.0  # px
    sigma_i: float = 8.0  # grey levels
    gamma: float = 0.3  # similarity threshold of homogeneous pixels
    band: float = 3.0  # band half-width per unit of dissimilarity W (disparity px)
    literal_eq3: bool = False  # homogeneous pixels by eq. 3 as printed (W > gamma); only to reproduce that reading


@dataclass(frozen=True)
class DiffusionConfig:
    """Diffusion guidance (Shivakumar et al. 2019; :mod:`..diffusion`)."""

    radius: int = 5  # half side of the neighbourhood a measurement spreads to (px)
    sigma_s: float = 10.0  # spatial width of the bilateral weight (px)
    sigma_i: float = 20.0  # colour width (grey levels)


@dataclass(frozen=True)
class PlusConfig:
    """riverbed+ settings (:mod:`..riverbed_plus`; docs/riverbed_plus.md)."""

    hops: object = "auto"  # support-region hops, or "auto" (round(spacing / 6), clipped to 1..8)
    margin: float = 2.0  # band half-margin around the connected LiDAR range (disparity px)
    confidence: str = "lr"  # "lr": extend only to pixels failing a first pass's left-right check; "none": to all
    lr_threshold: int = 1  # px
    arm_l1: int = 34  # cross construction (Mei et al. 2011 values)
    arm_l2: int = 17
    arm_tau1: int = 20
    arm_tau2: int = 6


@dataclass(frozen=True)
class ADCensusConfig:
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


@dataclass(frozen=True)
class TubeConfig:
    """LiDAR tubes: each pixel's search range from the LiDAR around it (:mod:`..tubes`, docs/tubes.md)."""

    reach: float = 2.0  # radius of the first level, in mean LiDAR spacings (1 / sqrt(share) px)
    margin: float = 2.0  # disparity margin (px) around the LiDAR extrema at the first level
    levels: int = 3  # levels (radius doubling each) before a pixel falls back to the nominal range
    level_margin: float = 4.0  # margin added per level (px): farther LiDAR, wider tube
    cell: int = 4  # cell side (px) in which LiDAR extrema are gathered
    max_spacing: float = 40.0  # LiDAR sparser than this (mean spacing, px) bounds no pixel: the nominal range
    holes: str = "full"  # pixels with no LiDAR within reach: the nominal range (full) or a coarse match's (coarse)


@dataclass(frozen=True)
class FuseConfig:
    """The confidence fusion (:mod:`..fusion`, docs/fusion.md)."""

    gate: float = 4.0  # stereo and LiDAR agree within this many standard deviations
    neighbours: int = 6  # LiDAR points of the leave-one-out plane fit
    support: int = 4  # LiDAR points whose residual RMS is a point's sigma
    floor: float = 0.25  # smallest LiDAR sigma (px)
    stereo_sigma: object = "auto"  # the stereo's error (px), or auto: estimated on the image
    lidar: str = "auto"  # the LiDAR's interpolation: auto, planes (local least-squares planes), linear (Delaunay)


_GROUPS = {"sgm": SGMConfig, "guidance": GuidanceConfig, "diffusion": DiffusionConfig, "plus": PlusConfig,
           "adcensus": ADCensusConfig, "tube": TubeConfig,
           "fuse": FuseConfig}


@dataclass(frozen=True)
class MatchConfig:
    """Everything :func:`~riverbed_cli.matching.pipeline.match_pair` is told, nested by matcher and guide."""

    matcher: str = "sgm"
    guide: str = "riverbed"
    census: str = "9x7"  # census window WIDTHxHEIGHT (both matchers)
    subpixel: bool = True
    median: int = 3
    range: str = "auto"  # disparity search range: auto (tube with LiDAR guidance, else full), tube, tile, full
    fusion: str = "auto"  # auto (confidence with LiDAR guidance, else none), confidence, none
    lidar_offset: object = "auto"  # the LiDAR's disparity offset: auto (estimated), none, DD or "DX,DY,DD" (px)
    lidar_check: str = "auto"  # drop the LiDAR the images contradict (outliers, changed regions): auto or off
    sgm: SGMConfig = field(default_factory=SGMConfig)
    guidance: GuidanceConfig = field(default_factory=GuidanceConfig)
    diffusion: DiffusionConfig = field(default_factory=DiffusionConfig)
    plus: PlusConfig = field(default_factory=PlusConfig)
    adcensus: ADCensusConfig = field(default_factory=ADCensusConfig)
    tube: TubeConfig = field(default_factory=TubeConfig)
    fuse: FuseConfig = field(default_factory=FuseConfig)

    def replace(self, **changes):
        """A copy with flat settings (``p2=150``, names of :data:`MATCH_SETTINGS`) or whole groups replaced.

        A group may be given as its object, as a dict of its fields, or as None (its defaults). Values are taken
        as given (validation is the command line's and the manifest's job, through :func:`validate_settings`).
        """
        top, groups = {}, {}
        for key, value in changes.items():
            if key in _GROUPS:
                if value is None:
                    value = _GROUPS[key]()
                elif isinstance(value, dict):
                    value = _GROUPS[key](**value)
                elif not isinstance(value, _GROUPS[key]):
                    raise RiverbedError(f"{key}: expected a {_GROUPS[key].__name__}, got {type(value).__name__}")
                top[key] = value
                continue
            s = SETTINGS_BY_NAME.get(key)
            if s is None or s.group is None:
                raise RiverbedError(f"unknown matching setting '{key}'")
            if s.group == "match":
                top[s.field] = value
            else:
                groups.setdefault(s.group, {})[s.field] = value
        out = replace(self, **top)
        if groups:
            out = replace(out, **{g: replace(getattr(out, g), **kv) for g, kv in groups.items()})
        return out

    def to_settings(self):
        """The flat settings (``{name: value}`` of every matching row of :data:`MATCH_SETTINGS`)."""
        out = {}
        for s in MATCH_SETTINGS:
            if s.group is None:
                continue
            holder = self if s.group == "match" else getattr(self, s.group)
            out[s.name] = getattr(holder, s.field)
        return out

    @classmethod
    def from_settings(cls, settings):
        """A config from flat settings; keys that are not matching settings (tile, min_disp, ...) are ignored."""
        return cls().replace(**{k: v for k, v in settings.items()
                                if k in SETTINGS_BY_NAME and SETTINGS_BY_NAME[k].group is not None})


def _group_rows(group, cls, prefix, applies, helps, kinds, checks, applies_to=None):
    """Rows for every field of a group dataclass: ``prefix + field`` names, defaults from the dataclass; ``kinds``
    and ``applies_to`` override a field's kind (command-line reading) and the matchers/guides it applies to."""
    applies_to = applies_to or {}
    return [Setting(prefix + f.name, f.default, checks[f.name], helps[f.name], group, f.name,
                    applies_to.get(f.name, applies), kinds.get(f.name, _kind_of(f.default)))
            for f in fields(cls)]


def _kind_of(default):
    if isinstance(default, bool):
        return "bool"
    if isinstance(default, int):
        return "int"
    if isinstance(default, float):
        return "float"
    return "str"


_NN = integer(0)
_POS = number(positive=True)

_SGM_HELP = {
    "paths": "SGM path directions.",
    "p1": "SGM penalty for a 1 px disparity change (Hamming units).",
    "p2": "SGM penalty for a larger disparity change (Hamming units).",
    "lr_check": "Invalidate pixels failing the left-right consistency check (AD-Census always checks and refills "
                "them in its refinement).",
    "lr_threshold": "Left-right check tolerance (px).",
    "outside_cost": "Cost where the match leaves the right image (Hamming units), or auto: a quarter of the census "
                    "bits.",
    "cost_scale": "Guided SGM costs are kept in uint16 at 1/cost_scale of a Hamming unit.",
}
_SGM_CHECKS = {"paths": choice((4, 8, 16)), "p1": _NN, "p2": _NN, "lr_check": boolean, "lr_threshold": _NN,
               "outside_cost": auto_or(_NN, "an integer >= 0"), "cost_scale": integer(1, 64)}

_GUIDANCE_HELP = {
    "k": "Height of the guidance walls (times the wall scale).",
    "c": "Width of the guidance walls (disparity px).",
    "form": "Wall form: additive (k F_bar (1 - exp(-t^2 / 2c^2)) added) or product (the paper's literal form).",
    "wall_scale": "F_bar of the additive walls (plain cost units), or auto: half the largest cost.",
    "window": "Riverbed window side s (odd px), or auto: smallest odd s with s*s*p >= window_target "
              "(p = LiDAR share), within [5, 25].",
    "window_target": "Auto window: LiDAR points wanted per window.",
    "sigma_xy": "Spatial width of the riverbed similarity (px).",
    "sigma_i": "Colour width of the riverbed similarity (grey levels).",
    "gamma": "Similarity threshold of homogeneous pixels (also the weight a diffusion pixel needs to be vouched for).",
    "band": "Band half-width per unit of dissimilarity (disparity px).",
    "literal_eq3": "Homogeneous pixels by eq. 3 as printed (W > gamma), only to reproduce that reading.",
}
_GUIDANCE_CHECKS = {"k": number(0), "c": _POS, "form": choice(FORMS), "wall_scale": auto_or(_POS, "a positive number"),
                    "window": auto_or(odd_window_upto(MAX_WINDOW), f"an odd integer from 1 to {MAX_WINDOW}"),
                    "window_target": _POS,
                    "sigma_xy": _POS, "sigma_i": _POS, "gamma": number(0), "band": number(0),
                    "literal_eq3": boolean}
_GUIDANCE_APPLIES = {"k": "gauss, riverbed, riverbed+", "c": "gauss, riverbed, riverbed+",
                     "form": "gauss, riverbed, riverbed+", "wall_scale": "gauss, riverbed, riverbed+",
                     "gamma": "riverbed, riverbed+, diffusion", "literal_eq3": "riverbed"}

_DIFFUSION_HELP = {"radius": "Half side of the neighbourhood a LiDAR measurement spreads to (px).",
                   "sigma_s": "Spatial width of the diffusion weight (px).",
                   "sigma_i": "Colour width of the diffusion weight (grey levels)."}
_DIFFUSION_CHECKS = {"radius": _NN, "sigma_s": _POS, "sigma_i": _POS}

_PLUS_HELP = {
    "hops": "Support-region hops, or auto: round(spacing / 6) within 1..8 (spacing = 1 / sqrt(LiDAR share)).",
    "margin": "Band half-margin around the connected LiDAR range (disparity px).",
    "confidence": "lr: extend only to pixels failing a first pass's left-right check; none: to every pixel.",
    "lr_threshold": "First pass's left-right check tolerance (px).",
    "arm_l1": "Cross arm length L1 (px).", "arm_l2": "Cross arm length L2 (px).",
    "arm_tau1": "Cross colour threshold tau1.", "arm_tau2": "Cross colour threshold tau2 (past L2).",
}
_PLUS_CHECKS = {"hops": auto_or(integer(0), "an integer >= 0"), "margin": number(0), "confidence": choice(CONFIDENCES),
                "lr_threshold": _NN, "arm_l1": integer(1, 255), "arm_l2": integer(1, 255),
                "arm_tau1": _NN, "arm_tau2": _NN}

_TUBE_HELP = {"reach": "Tube: radius of the first level, in mean LiDAR spacings.",
              "margin": "Tube: disparity margin around the LiDAR extrema at the first level (px).",
              "levels": "Tube: levels (radius doubling) before a pixel falls back to the nominal range.",
              "level_margin": "Tube: margin added per level (px).",
              "cell": "Tube: cell side (px) in which LiDAR extrema are gathered.",
              "max_spacing": "Tube: LiDAR sparser than this mean spacing (px) bounds no pixel (nominal range).",
              "holes": "Tube: what pixels with no LiDAR within reach search: full (the nominal range) or coarse (the "
                       "range of an unguided match of the pair at half resolution, as tSGM; a tiled match takes each "
                       "tile's own; docs/tubes.md)."}
_TUBE_CHECKS = {"reach": _POS, "margin": number(0), "levels": integer(1, 12), "level_margin": number(0),
                "cell": integer(1, 64), "max_spacing": _POS, "holes": choice(TUBE_HOLES)}

_FUSE_HELP = {"gate": "Fusion: stereo and LiDAR agree within this many standard deviations.",
              "neighbours": "Fusion: LiDAR points of the leave-one-out plane fit that measures the LiDAR's error.",
              "support": "Fusion: LiDAR points whose residual RMS is a point's error.",
              "floor": "Fusion: smallest LiDAR error (px).",
              "stereo_sigma": "Fusion: the stereo's error (px), or auto: estimated where the LiDAR is planar.",
              "lidar": "Fusion: the LiDAR's interpolation: planes (each pixel on the least-squares plane of its "
                       "nearest LiDAR point and that point's natural neighbours; no triangulation), linear "
                       "(Delaunay; about three times the cost of planes on dense "
                       "LiDAR), or auto: planes for LiDAR denser than one point per 12 x 12 px, else linear."}
_FUSE_CHECKS = {"gate": _POS, "neighbours": integer(3, 64), "support": integer(1, 64), "floor": _POS,
                "stereo_sigma": auto_or(_POS, "a positive number"), "lidar": choice(LIDAR_KINDS)}

_ADC_HELP = {
    "lambda_ad": "AD cost scale lambda_AD.", "lambda_census": "Census cost scale lambda_census.",
    "scale": "Fixed-point cost units per 1.0 of the paper's cost.",
    "outside": "Cost (paper units) where the match leaves the right image.",
    "arm_l1": "Cross arm length L1 (px).", "arm_l2": "Cross arm length L2 (px).",
    "arm_tau1": "Cross colour threshold tau1.", "arm_tau2": "Cross colour threshold tau2 (past L2).",
    "iterations": "Cross aggregation iterations.",
    "pi1": "Scanline optimisation penalty Pi1.", "pi2": "Scanline optimisation penalty Pi2.",
    "tau_so": "Scanline optimisation colour threshold tau_SO.",
    "lr_threshold": "Left-right check tolerance (px).",
    "vote_iterations": "Region voting iterations.", "vote_ts": "Region voting: least votes tau_S.",
    "vote_th": "Region voting: least share tau_H.",
    "interpolate": "Proper interpolation of outliers.", "discontinuity": "Depth discontinuity adjustment.",
    "edge_threshold": "Sobel |gx| + |gy| of the disparity above which a pixel is a disparity edge.",
    "guide_stage": "Where guidance modulates the volume: aggregated (before scanline optimisation) or initial.",
}
_ADC_CHECKS = {"lambda_ad": _POS, "lambda_census": _POS, "scale": integer(1, 4096), "outside": number(0),
               "arm_l1": integer(1, 255), "arm_l2": integer(1, 255), "arm_tau1": _NN, "arm_tau2": _NN,
               "iterations": _NN, "pi1": number(0), "pi2": number(0), "tau_so": _NN, "lr_threshold": _NN,
               "vote_iterations": _NN, "vote_ts": _NN, "vote_th": number(0), "interpolate": boolean,
               "discontinuity": boolean, "edge_threshold": number(0), "guide_stage": choice(GUIDE_STAGES)}


def lidar_offset(v):
    """``'auto'``, ``'none'``, a finite number DD or the text ``'DX,DY,DD'`` (px; DX, DY at most 64 px)."""
    if v in ("auto", "none"):
        return v
    if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v):
        return float(v)
    parts = str(v).split(",") if isinstance(v, str) else []
    try:
        nums = [float(p) for p in parts]
    except ValueError:
        nums = []
    if len(nums) in (1, 3) and all(math.isfinite(n) for n in nums) and all(abs(n) <= 64 for n in nums[:-1]):
        return nums[0] if len(nums) == 1 else ",".join(f"{n:g}" for n in nums)
    raise SettingError(f"expected auto, none, DD or DX,DY,DD (px; DX and DY at most 64), got {show(v)}")


def lidar_check_mode(v):
    """``'auto'`` or ``'off'`` (YAML's unquoted ``off`` and ``on`` read as booleans: taken as ``off`` and ``auto``)."""
    if isinstance(v, bool):
        return "auto" if v else "off"
    if isinstance(v, str) and v.strip().lower() in LIDAR_CHECKS:
        return v.strip().lower()
    raise SettingError(f"expected one of {', '.join(LIDAR_CHECKS)}, got {show(v)}")


def tile_size(v):
    """A tile side: ``'auto'``, ``0`` (never tile) or an integer >= 16 (px)."""
    if v == "auto" or v == 0 and not isinstance(v, bool):
        return v
    if isinstance(v, bool) or not isinstance(v, int) or v < 16:
        raise SettingError(f"expected 'auto' or an integer >= 16 (px), got {show(v)}; 0 never tiles")
    return v


MATCH_SETTINGS = (
    # the matcher and what every matcher shares
    Setting("matcher", "sgm", choice(MATCHER_NAMES),
            "sgm: census cost + Semi-Global Matching; adcensus: AD-Census (Mei et al. 2011: AD + census cost, "
            "cross-based aggregation, scanline optimisation, multi-step refinement).", "match", "matcher"),
    Setting("guide", "riverbed", choice(GUIDE_NAMES),
            "Cost-volume guidance: gauss (Poggi et al.), riverbed (the paper), diffusion (Shivakumar et al. 2019), "
            "riverbed+ (riverbed extended through cross-based support regions to the pixels failing a first pass's "
            "left-right check; docs/riverbed_plus.md). Default: riverbed with sparse LiDAR, else none.",
            "match", "guide"),
    Setting("census", "9x7", census_window, "Census window WIDTHxHEIGHT.", "match", "census"),
    Setting("subpixel", True, boolean, "Parabola sub-pixel fit.", "match", "subpixel", kind="bool"),
    Setting("median", 3, integer(0, 15), "Median filter size (1 or 0: off).", "match", "median", kind="int"),
    Setting("range", "auto", choice(RANGES),
            "Disparity search range per pixel: tube (from the LiDAR around each pixel, docs/tubes.md), tile (one "
            "range per tile, from its LiDAR), full (the nominal range everywhere); auto: tube for LiDAR-guided "
            "sgm, else full.", "match", "range"),
    Setting("fusion", "auto", choice(FUSION_CHOICES),
            "Combine the matched disparity with the LiDAR's interpolation per pixel: confidence (docs/fusion.md), "
            "none (the matcher's output: the paper's method); auto: confidence with LiDAR guidance, else none.",
            "match", "fusion"),
    Setting("lidar_offset", "auto", lidar_offset,
            "The LiDAR's offset against the images (px, LiDAR minus images): auto (estimated from the images at the "
            "LiDAR points, removed when at least 1 px; docs/lidar_faults.md), none (the LiDAR as it is: the paper's "
            "method), DD (a disparity offset removed) or DX,DY,DD (the points also moved back by DX, DY px).",
            "match", "lidar_offset"),
    Setting("lidar_check", "auto", lidar_check_mode,
            "Check the LiDAR against the images before it guides: auto drops gross outliers and the points of "
            "changed regions (docs/lidar_faults.md), off keeps every point (the paper's method).",
            "match", "lidar_check"),
    # census + SGM
    *_group_rows("sgm", SGMConfig, "", "sgm", _SGM_HELP, {"paths": "choice-int", "outside_cost": "auto-int"},
                 _SGM_CHECKS),
    # Gauss and riverbed guidance
    *_group_rows("guidance", GuidanceConfig, "", "riverbed, riverbed+", _GUIDANCE_HELP,
                 {"window": "auto-int", "wall_scale": "auto-float"}, _GUIDANCE_CHECKS, _GUIDANCE_APPLIES),
    *_group_rows("diffusion", DiffusionConfig, "diffusion_", "diffusion", _DIFFUSION_HELP, {}, _DIFFUSION_CHECKS),
    *_group_rows("plus", PlusConfig, "plus_", "riverbed+", _PLUS_HELP, {"hops": "auto-int"}, _PLUS_CHECKS),
    *_group_rows("adcensus", ADCensusConfig, "adcensus_", "adcensus", _ADC_HELP, {}, _ADC_CHECKS),
    *_group_rows("tube", TubeConfig, "tube_", "range tube", _TUBE_HELP, {}, _TUBE_CHECKS),
    *_group_rows("fuse", FuseConfig, "fusion_", "fusion confidence", _FUSE_HELP, {"stereo_sigma": "auto-float"},
                 _FUSE_CHECKS),
    # the run: disparity range, input size, tiling (not part of MatchConfig)
    Setting("min_disp", None, integer(-100_000, 100_000, none=True),
            "Smallest disparity searched (px, inclusive; default: from the sparse LiDAR, else 0).", kind="int"),
    Setting("max_disp", None, integer(-100_000, 100_000, none=True),
            "Largest disparity searched (px, inclusive; default: from the sparse LiDAR with a margin).", kind="int"),
    Setting("max_pixels", MAX_PIXELS, integer(1), "Refuse images larger than this (width x height).", kind="int"),
    Setting("tile", TILE_DEFAULT, tile_size,
            "Tile side (px) for large images, auto (from the disparity range and free memory; untiled when the "
            "image fits one tile) or 0 (never tile).", kind="auto-int"),
    Setting("overlap", OVERLAP_DEFAULT, integer(0), "Tile overlap (px).", kind="int"),
    Setting("lidar_range", True, boolean,
            "With tiles and sparse LiDAR: each tile searches only the disparities its LiDAR allows.", kind="bool"),
)

SETTINGS_BY_NAME = {s.name: s for s in MATCH_SETTINGS}


def validate_setting(name, value):
    """The value of setting ``name`` normalised; :class:`SettingError` with the one-line reason if it is wrong."""
    return SETTINGS_BY_NAME[name].validate(value)


def validate_settings(settings):
    """Cross-setting checks of a complete flat settings dict (after each value passed :func:`validate_setting`).

    Returns the one-line problem, or None.
    """
    lo, hi = settings.get("min_disp"), settings.get("max_disp")
    if lo is not None and hi is not None and lo > hi:
        return f"min_disp {lo} > max_disp {hi}"
    return None


def default_settings():
    """Every setting of :data:`MATCH_SETTINGS` at its default (a fresh dict)."""
    return {s.name: s.default for s in MATCH_SETTINGS}
