"""Registries of matchers, guides and fusions: plain dicts, filled by the ``register_*`` decorators of
``matching/matchers/``, ``matching/guides/`` and ``matching/fusion.py``.

A new guide is one module in ``matching/guides/`` with a :class:`~.guides.base.Guide` subclass decorated by
:func:`register_guide`, its import in ``guides/__init__.py``, and its name and settings in :mod:`.config` (where
the command line and the manifest read them without loading any kernel).
"""

from ..errors import RiverbedError
from .config import FUSION_NAMES, GUIDE_NAMES, MATCHER_NAMES

MATCHERS = {}
GUIDES = {}
FUSIONS = {}


def _register(table, names, kind):
    def decorate(cls):
        if cls.name not in names:
            raise RuntimeError(f"{kind} '{cls.name}' is not declared in matching/config.py ({', '.join(names)})")
        table[cls.name] = cls()
        return cls
    return decorate


register_matcher = _register(MATCHERS, MATCHER_NAMES, "matcher")
register_guide = _register(GUIDES, GUIDE_NAMES, "guide")
register_fusion = _register(FUSIONS, FUSION_NAMES, "fusion")


def get_matcher(name):
    """The registered matcher ``name``; :class:`RiverbedError` naming the valid ones otherwise."""
    if name not in MATCHERS:
        raise RiverbedError(f"unknown matcher '{name}' (use one of {', '.join(MATCHER_NAMES)})")
    return MATCHERS[name]


def get_guide(name):
    """The registered guide ``name``; :class:`RiverbedError` naming the valid ones otherwise."""
    if name not in GUIDES:
        raise RiverbedError(f"unknown guide '{name}' (use one of {', '.join(GUIDE_NAMES)})")
    return GUIDES[name]


def get_fusion(name):
    """The registered fusion ``name``; :class:`RiverbedError` naming the valid ones otherwise."""
    if name not in FUSIONS:
        raise RiverbedError(f"unknown fusion '{name}' (use one of {', '.join(FUSION_NAMES)})")
    return FUSIONS[name]
