"""Guides of the cost volume, one module each, registered by name in :data:`..registry.GUIDES`.

``none``, ``gauss`` (Poggi et al. 2019), ``riverbed`` (the paper), ``diffusion`` (Shivakumar et al. 2019) and
``riverbed+`` (riverbed through support regions; docs/riverbed_plus.md). The arithmetic lives in the stage modules
(:mod:`..guidance`, :mod:`..diffusion`, :mod:`..riverbed_plus`); a guide here says what it needs and calls it.
"""

from . import diffusion, gauss, none, riverbed, riverbed_plus  # noqa: F401  (importing registers them)
from .base import Guidance, GuidanceInputs, Guide  # noqa: F401
