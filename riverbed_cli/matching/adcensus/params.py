"""AD-Census settings and where guidance may act on the volume: defined with every matching setting in
:mod:`riverbed_cli.matching.config` (one table for the command line, manifests and the library)."""

from ..config import GUIDE_STAGES  # noqa: F401  (guidance on the aggregated volume, before SO, or on the raw cost)
from ..config import ADCensusConfig as ADCensusParams  # noqa: F401
