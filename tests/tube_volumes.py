"""Tube-volume helpers and brute-force references shared by the dense and tube tests (tests/test_tubes.py,
tests/test_adcensus.py, tests/test_adcensus_tubes.py)."""

import numpy as np

UNREACHABLE = 10 ** 9


def blocky(rng, H, W, C=3, levels=40):
    """Random image with flat-ish blocks (long arms) and sharp edges (short arms)."""
    img = rng.integers(0, levels, (H, W, C)).astype(np.int32)
    img[:, W // 3:] += 90
    img[H // 2:, :] += 60
    return np.clip(img, 0, 255).astype(np.uint8)


def gather(dense, layout):
    """The tube entries of a dense (H, W, D) volume (index 0 at offset 0), as a flat tube volume."""
    H, W = layout.shape
    out = np.empty(layout.size, dense.dtype)
    for y in range(H):
        for x in range(W):
            b, w, o = layout.start[y, x], layout.width[y, x], layout.offset[y, x]
            out[b:b + w] = dense[y, x, o:o + w]
    return out


def scanline_ref(cost, left, right, d_min, p1t, p2t, tau, lo=None, hi=None):
    """AD-Census's four-path scanline optimisation with colour-dependent penalties, every recursion written out, on a
    dense (H, W, D) volume. With tubes (inclusive index bounds ``lo``, ``hi``; default the whole range) a disparity
    outside the previous pixel's tube is unreachable there. Returns the sum of the paths (valid inside the tubes)."""
    H, W, D = cost.shape
    if lo is None:
        lo, hi = np.zeros((H, W), int), np.full((H, W), D - 1)
    L = left.reshape(H, W, -1).astype(int)
    R = right.reshape(H, W, -1).astype(int)
    C = cost.astype(np.int64)
    total = np.zeros((H, W, D), np.int64)
    for dx, dy in [(1, 0), (0, 1), (-1, 0), (0, -1)]:
        Lr = np.full((H, W, D), UNREACHABLE, np.int64)
        for y in (range(H) if dy >= 0 else range(H - 1, -1, -1)):
            for x in (range(W) if dx >= 0 else range(W - 1, -1, -1)):
                py, px = y - dy, x - dx
                tube = range(lo[y, x], hi[y, x] + 1)
                if not (0 <= py < H and 0 <= px < W):
                    for i in tube:
                        Lr[y, x, i] = C[y, x, i]
                    continue
                d1 = np.abs(L[y, x] - L[py, px]).max()
                prev = Lr[py, px]  # UNREACHABLE outside the previous pixel's tube
                mp = prev[lo[py, px]:hi[py, px] + 1].min()
                for i in tube:
                    xr, pxr = x - d_min - i, x - d_min - i - dx
                    d2 = np.abs(R[y, xr] - R[py, pxr]).max() if (0 <= xr < W and 0 <= pxr < W) else d1
                    cat = int(d1 >= tau) + int(d2 >= tau)
                    best = min(prev[i], mp + p2t[cat])
                    if i > 0:
                        best = min(best, prev[i - 1] + p1t[cat])
                    if i < D - 1:
                        best = min(best, prev[i + 1] + p1t[cat])
                    Lr[y, x, i] = C[y, x, i] + best - mp
        total += np.where(Lr < UNREACHABLE, Lr, 0)
    return total
