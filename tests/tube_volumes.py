"""Tube-volume helpers shared by the tube tests (tests/test_tubes.py, tests/test_adcensus_tubes.py)."""

import numpy as np


def gather(dense, layout):
    """The tube entries of a dense (H, W, D) volume (index 0 at offset 0), as a flat tube volume."""
    H, W = layout.shape
    out = np.empty(layout.size, dense.dtype)
    for y in range(H):
        for x in range(W):
            b, w, o = layout.start[y, x], layout.width[y, x], layout.offset[y, x]
            out[b:b + w] = dense[y, x, o:o + w]
    return out
