"""Matchers, one module each, registered by name in :data:`..registry.MATCHERS`: ``sgm`` (census + SGM) and
``adcensus`` (Mei et al. 2011)."""

from . import adcensus, sgm  # noqa: F401  (importing registers them)
from .base import Matcher, MatcherOutput  # noqa: F401
