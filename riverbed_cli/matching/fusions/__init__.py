"""Fusions of the matcher's output with the LiDAR, one module each, registered by name in
:data:`..registry.FUSIONS`.

``none`` (the paper's method) and ``confidence`` (docs/fusion.md). The arithmetic lives in the stage module
:mod:`..fusion`; a fusion here says what it needs and calls it.
"""

from . import confidence, none  # noqa: F401  (importing registers them)
from .base import Fusion  # noqa: F401
