"""``adcensus``: AD-Census (Mei et al. 2011; the stages in :mod:`..adcensus`), guided between cross aggregation and
scanline optimisation (or on the raw cost, ``adcensus_guide_stage: initial``); on the full range or on per-pixel
tubes (docs/tubes.md, "AD-Census")."""

from ...io.images import effective_bits, to_grey, to_guide
from .. import census, guidance
from ..guides.base import GuidanceInputs
from ..registry import get_guide, register_matcher
from ..volume import CostVolume
from .base import Matcher, MatcherOutput


@register_matcher
class ADCensusMatcher(Matcher):
    name = "adcensus"

    supports_tubes = True
    # its exact tube cross aggregation holds 1.6-3.8x the tubes' costs, at 8-10 bytes each (docs/tubes.md): tiles
    # stay sized for the nominal volume
    tube_sized_tiles = False

    def match(self, left, right, sparse, d_min, d_max, config, guide, share, first_pass, stages, tubes=None,
              return_status=False, points=None):
        from .. import adcensus  # its kernels' module loads with the runs that use it (start-up)

        ap = config.adcensus
        bits = effective_bits(left, right)
        guide_img = to_guide(left, bits)
        il, ir = adcensus.to_u8(guide_img), adcensus.to_u8(to_guide(right, bits))
        grey = (to_grey(left, bits), to_grey(right, bits))
        used = {"window": None}
        modulate = None
        if guide.needs_sparse:
            # int16 scanline paths: a guided cost plus the largest penalty must stay below 16384 (and each half-sum
            # of two paths within int16)
            max_cost = 16383 - int(adcensus.so_penalties(ap.pi1, ap.pi2, ap.scale)[1][0])
            # wall scale: half the largest AD-Census cost (1.0 of the paper's [0, 2]), as half the census bits
            g = config.guidance
            wall_scale = 1.0 if g.wall_scale == "auto" else float(g.wall_scale)
            inputs = GuidanceInputs(sparse, guide_img, share, wall_scale, max_cost, first_pass, want_support=True,
                                    points=points)

            def modulate(data, max_cost, layout):
                result = guide.modulate(CostVolume(data, d_min, ap.scale, max_cost, layout), inputs, config)
                used["window"] = result.window
                return result.volume.data, result.volume.max_cost, result.support

        timings = {}
        disp, ref = adcensus.adcensus_disparity(il, ir, d_min, d_max, ap, census.parse_census_window(config.census),
                                                grey, modulate, config.subpixel, config.median, timings,
                                                return_status=return_status, tubes=tubes)
        stages.update({k: round(v, 4) for k, v in timings.items()})
        status = ref.pop("status") if return_status else None
        return MatcherOutput(disp, used["window"], ref, status)

    def unreliable(self, left, right, sparse, d_min, d_max, config, lr_threshold, tubes=None):
        # AD-Census always checks left-right consistency; its own status map says which pixels failed
        out = self.match(left, right, sparse, d_min, d_max, config, get_guide(config.guide),
                         guidance.lidar_share(sparse), None, {}, tubes, return_status=True)
        return out.status > 0
