"""``sgm``: census cost, guidance, Semi-Global Matching, winner-takes-all with sub-pixel fit, median.

Stages: :func:`..census.census_cost` -> the guide -> :func:`..sgm.sgm_aggregate_select` (SGM's passes and the
disparity selection, :func:`..disparity.select_row`, in one kernel: the ``aggregation`` stage holds both) ->
:func:`..disparity.median_filter`.
"""

import time

import numpy as np

from ...errors import RiverbedError
from ...io.images import effective_bits, guide_source, to_grey
from .. import census, disparity, guidance, sgm
from ..guides.base import GuidanceInputs
from ..registry import get_guide, register_matcher
from ..volume import CostVolume
from .base import Matcher, MatcherOutput


def _lap(stages, name, t0):
    stages[name] = round(time.perf_counter() - t0, 4)


@register_matcher
class SGMMatcher(Matcher):
    name = "sgm"

    supports_tubes = True
    tube_sized_tiles = True

    def match(self, left, right, sparse, d_min, d_max, config, guide, share, first_pass, stages, tubes=None,
              return_status=False, points=None):
        s = config.sgm
        t0 = time.perf_counter()
        win = census.parse_census_window(config.census)
        nbits = win[0] * win[1] - 1
        outside = nbits // 4 if s.outside_cost == "auto" else int(s.outside_cost)
        guided = guide.needs_sparse
        scale = int(s.cost_scale) if guided else 1
        bits = effective_bits(left, right)  # one scale for both images of a 16-bit pair
        cl = census.census_transform(to_grey(left, bits), win)
        cr = census.census_transform(to_grey(right, bits), win)
        # with tubes (a TubeLayout) the volume holds only each pixel's own disparities, flat
        volume = CostVolume(census.census_cost(cl, cr, d_min, d_max, outside, scale, tubes), d_min, scale,
                            max(nbits, outside) * scale, tubes)
        del cl, cr
        _lap(stages, "cost", t0)

        window = None
        t0 = time.perf_counter()
        if guided:
            max_cost = 65535 // s.paths - s.p2 * scale
            # A fixed wall scale (not the mean cost at this image's LiDAR pixels) keeps tiles consistent with the
            # whole image; the walls' height barely matters (docs/method.md).
            g = config.guidance
            wall_scale = nbits / 2.0 if g.wall_scale == "auto" else float(g.wall_scale)
            if max_cost <= nbits * scale:
                raise RiverbedError(f"P2 {s.p2} is too large for {s.paths} paths with guided uint16 costs")
            image = guide_source(left, bits) if guide.needs_image else None
            inputs = GuidanceInputs(sparse, image, share, wall_scale, max_cost, first_pass, points=points)
            result = guide.modulate(volume, inputs, config)
            volume, window = result.volume, result.window
        _lap(stages, "guidance", t0)

        t0 = time.perf_counter()
        # aggregation and selection in one kernel: a row's disparity is selected while the other pass goes on
        disp = sgm.sgm_aggregate_select(volume.data, s.p1 * scale, s.p2 * scale, d_min, s.paths,
                                        max_cost=volume.max_cost, tubes=tubes, subpixel=config.subpixel,
                                        lr_check=s.lr_check, lr_threshold=s.lr_threshold,
                                        return_status=return_status)
        del volume
        status = None
        if return_status:
            disp, status = disp
        _lap(stages, "aggregation", t0)  # the selection's time included

        t0 = time.perf_counter()
        disp = disparity.median_filter(disp, config.median)
        _lap(stages, "refinement", t0)
        return MatcherOutput(disp, window, status=status)

    def unreliable(self, left, right, sparse, d_min, d_max, config, lr_threshold, tubes=None):
        config = config.replace(lr_check=True, lr_threshold=lr_threshold, median=1)
        out = self.match(left, right, sparse, d_min, d_max, config, get_guide(config.guide),
                         guidance.lidar_share(sparse), None, {}, tubes)
        return ~np.isfinite(out.disparity)
