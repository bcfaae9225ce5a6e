"""Typed results that read like the dicts they replace: ``info["seconds"]``, ``{**info}``, ``info.to_dict()``."""

from collections.abc import Mapping
from dataclasses import fields


class RecordMapping(Mapping):
    """A dataclass read as a mapping of its fields; fields that are None and marked ``optional`` are left out."""

    _optional = ()

    def to_dict(self):
        out = {}
        for f in fields(self):
            v = getattr(self, f.name)
            if v is None and f.name in self._optional:
                continue
            out[f.name] = v
        return out

    def __getitem__(self, key):
        d = self.to_dict()
        return d[key]

    def __iter__(self):
        return iter(self.to_dict())

    def __len__(self):
        return len(self.to_dict())
