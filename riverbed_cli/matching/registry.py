"""Registries of matchers, guides and fusions: dicts filled by the ``register_*`` decorators of
``matching/matchers/``, ``matching/guides/`` and ``matching/fusions/``, which load those modules on first access.

A new guide is one module in ``matching/guides/`` with a :class:`~.guides.base.Guide` subclass decorated by
:func:`register_guide`, its import in ``guides/__init__.py``, and its name and settings in :mod:`.config` (where
the command line and the manifest read them without loading any kernel).
"""

import importlib

from ..errors import RiverbedError
from .config import FUSION_NAMES, GUIDE_NAMES, MATCHER_NAMES


class Registry(dict):
    """A table of name -> plugin, filled by the ``register_*`` decorator as its plugin ``package`` is imported. Read
    through it (``[]``, ``in``, iteration, ``len``, ``keys``/``values``/``items``/``get``), the package is imported
    first: the table is full on first access, whoever imported what before."""

    def __init__(self, package):
        super().__init__()
        self._package = package

    def _load(self):
        if self._package is not None:
            package, self._package = self._package, None  # once (a plugin reading the table while it loads)
            importlib.import_module(package)

    def __getitem__(self, key):
        self._load()
        return super().__getitem__(key)

    def __contains__(self, key):
        self._load()
        return super().__contains__(key)

    def __iter__(self):
        self._load()
        return super().__iter__()

    def __len__(self):
        self._load()
        return super().__len__()

    def __repr__(self):
        self._load()
        return super().__repr__()

    def keys(self):
        self._load()
        return super().keys()

    def values(self):
        self._load()
        return super().values()

    def items(self):
        self._load()
        return super().items()

    def get(self, key, default=None):
        self._load()
        return super().get(key, default)


MATCHERS = Registry(f"{__package__}.matchers")
GUIDES = Registry(f"{__package__}.guides")
FUSIONS = Registry(f"{__package__}.fusions")


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
