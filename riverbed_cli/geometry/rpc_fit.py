"""Fitting an RPC model to a camera: least squares on ground points whose image positions the camera gives.

The usual "terrain-independent" fit (Tao & Hu 2001; rpcfit, Akiki et al. 2021, does the same with an L-curve
choice of the regularisation): a 3-D grid of ground points over the scene's extent and height range is projected
by the rigorous camera model, and the 78 coefficients of the two rationals are the least-squares solution of the
linearised equations ``N(L, P, H) - c D(L, P, H) = 0`` (``D``'s constant term fixed to 1), weighted by ``1 / D``
of the previous iteration so that the image-space residual ``c - N / D`` itself is minimised, with a small
Tikhonov term keeping the ill-determined denominator terms of a nearly affine camera small. The fit error is
measured on a separate check grid (:func:`rpc_fit_error`).

``rpcfit`` itself is not used: it imports ``rpcm``, which ``docs/rpc.md`` explains riverbed does not depend on.

Conventions are those of :mod:`riverbed_cli.geometry.rpc`: pixels ``(col, row)`` with the first pixel's centre
at ``(0, 0)``; ground WGS 84 longitude, latitude (degrees) and ellipsoidal height (m).
"""

import numpy as np

from ..errors import RiverbedError
from .rpc import RPC_TERMS, RPCModel

#: Tikhonov weight on the coefficients (normalised units; rpcfit's default: 1e-6 lets the denominators fit
#: the attitude jitter with poles inside the domain).
REGULARISATION = 1e-3
#: Reweighting iterations of the linearised least squares.
ITERATIONS = 10


def rpc_terms(L, P, H):
    """The 20 RPC00B cubic terms (order of :data:`RPC_TERMS`) at normalised coordinates, shape ``(N, 20)``."""
    L, P, H = (np.asarray(v, np.float64).ravel() for v in (L, P, H))
    return np.stack([L ** a * P ** b * H ** c for a, b, c in RPC_TERMS], axis=1)


def _normalisation(v):
    lo, hi = float(np.min(v)), float(np.max(v))
    off = 0.5 * (lo + hi)
    scale = 0.5 * (hi - lo)
    return off, scale if scale > 0 else 1.0


def _fit_rational(T, target, regularisation, iterations):
    """Coefficients (num 20, den 20 with den[0] = 1) of ``target ~ T num / T den``, reweighted least squares."""
    A = np.hstack([T, -target[:, None] * T[:, 1:]])
    w = np.ones(len(T))
    num = den = None
    for _ in range(iterations):
        # the regularised normal equations (39 x 39, as rpcfit solves them): an SVD of the tall system costs
        # 100 times more for the same solution at this conditioning
        Aw = A * w[:, None]
        x = np.linalg.solve(Aw.T @ Aw + regularisation * np.eye(39), Aw.T @ (target * w))
        num, den = x[:20], np.concatenate([[1.0], x[20:]])
        D = T @ den
        if np.any(np.abs(D) < 1e-6):
            raise RiverbedError("RPC fit: a denominator vanishes on the fit points (the camera is not rational "
                                "enough over this grid)")
        w = 1.0 / np.abs(D)
    return num, den


def fit_rpc(lon, lat, h, col, row, regularisation=REGULARISATION, iterations=ITERATIONS):
    """The RPC model (cubic rationals, RPC00B term order) that best maps ``(lon, lat, h)`` to ``(col, row)``.

    Parameters
    ----------
    lon, lat : array_like
        Ground points' WGS 84 longitude and latitude (degrees), e.g. a grid over the scene's footprint.
    h : array_like
        Their heights above the WGS 84 ellipsoid (m), spanning the scene's height range (several layers).
    col, row : array_like
        Their image positions (px, first pixel's centre at ``(0, 0)``) by the rigorous camera model.
    regularisation : float
        Tikhonov weight on the coefficients in normalised units.
    iterations : int
        Reweighting iterations (weights ``1 / D`` of the previous solution).

    Returns
    -------
    RPCModel
        Offsets at the centres of the points' ranges, scales their half ranges.
    """
    lon, lat, h, col, row = (np.asarray(v, np.float64).ravel() for v in (lon, lat, h, col, row))
    if not (len(lon) == len(lat) == len(h) == len(col) == len(row)) or len(lon) < 39:
        raise RiverbedError(f"RPC fit: needs at least 39 points with five equal-length coordinates, got {len(lon)}")
    if not all(np.all(np.isfinite(v)) for v in (lon, lat, h, col, row)):
        raise RiverbedError("RPC fit: non-finite coordinates among the fit points")
    norm = {"long": _normalisation(lon), "lat": _normalisation(lat), "height": _normalisation(h),
            "samp": _normalisation(col), "line": _normalisation(row)}
    T = rpc_terms((lon - norm["long"][0]) / norm["long"][1], (lat - norm["lat"][0]) / norm["lat"][1],
                  (h - norm["height"][0]) / norm["height"][1])
    sn, sd = _fit_rational(T, (col - norm["samp"][0]) / norm["samp"][1], regularisation, iterations)
    ln, ld = _fit_rational(T, (row - norm["line"][0]) / norm["line"][1], regularisation, iterations)
    d = {f"{k}_off": v[0] for k, v in norm.items()}
    d.update({f"{k}_scale": v[1] for k, v in norm.items()})
    d.update({"samp_num_coeff": sn, "samp_den_coeff": sd, "line_num_coeff": ln, "line_den_coeff": ld})
    return RPCModel.from_dict(d, source="fit", fmt="fit")


def rpc_fit_error(rpc, lon, lat, h, col, row):
    """Image-space error of ``rpc`` on check points: ``rpc.project(lon, lat, h) - (col, row)``.

    Returns
    -------
    dict
        ``rms_px`` (of the 2-D error), ``max_px`` (largest 2-D error), ``col_max_px``, ``row_max_px`` and ``n``.
    """
    c, r = rpc.project(lon, lat, h)
    ec = np.asarray(c, np.float64).ravel() - np.asarray(col, np.float64).ravel()
    er = np.asarray(r, np.float64).ravel() - np.asarray(row, np.float64).ravel()
    e = np.hypot(ec, er)
    return {"rms_px": float(np.sqrt(np.mean(e ** 2))), "max_px": float(e.max()),
            "col_max_px": float(np.abs(ec).max()), "row_max_px": float(np.abs(er).max()), "n": int(e.size)}
