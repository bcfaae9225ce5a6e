"""Accuracy gates of the tests: each measured figure against its reviewed expectation, committed in the test.

A figure passes when it lies within :data:`RELATIVE` (2 %, ``riverbed benchmark``'s own: the runs are deterministic,
riverbed_cli/products/benchmark.py) of its expectation, or within a small absolute floor
where 2 % of the value is less than that floor (0.01 percentage points for shares of pixels or cells, 0.001 px or m
for errors). The gate is two-sided: a figure that got much better is a change to review too (update the
expectation with the new measurement). The floors are small enough that a 5 % regression of every committed figure
fails (:func:`assert_catches`).
"""

from riverbed_cli.products.benchmark import RELATIVE  # one gate rule: riverbed benchmark --check's

#: metrics given in percent (of the evaluated pixels or cells); every other metric is a length (px or m)
PERCENT = ("bad1", "bad2", "bad3", "d1", "density", "over_3res", "over_0.5", "over_1", "over_2", "completeness")
FLOOR_PERCENT = 0.01  # percentage points
FLOOR_LENGTH = 0.001  # px or m


def tolerance(metric, expected, relative=RELATIVE):
    """The largest accepted distance of a ``metric`` figure from its ``expected`` value (``relative``: a tighter
    share for figures the tests reproduce exactly, with the same floors)."""
    return max(relative * abs(expected), FLOOR_PERCENT if metric in PERCENT else FLOOR_LENGTH)


def off_gate(got, expected, relative=RELATIVE):
    """Lines naming each ``(case, metric)`` of ``expected`` (``{case: {metric: value}}``) whose figure in ``got``
    (same layout) lies outside its tolerance; empty when all pass."""
    lines = []
    for case, metrics in expected.items():
        for metric, value in metrics.items():
            measured = got[case][metric]
            tol = tolerance(metric, value, relative)
            if not abs(measured - value) <= tol:
                lines.append(f"{case} {metric}: measured {measured:.4f}, expected {value} +- {tol:.4f} "
                             f"({100 * (measured - value) / value:+.1f} %)" if value else
                             f"{case} {metric}: measured {measured:.4f}, expected {value} +- {tol:.4f}")
    return lines


def assert_within(got, expected, relative=RELATIVE):
    """Every figure of ``expected`` within its tolerance in ``got``; the message lists every one that is not."""
    lines = off_gate(got, expected, relative)
    assert not lines, f"{len(lines)} figure(s) off their committed expectation:\n" + "\n".join(lines)


def assert_catches(expected, regression=0.05):
    """A ``regression`` (5 %) of any figure of ``expected``, up or down, falls outside its gate."""
    for case, metrics in expected.items():
        for metric, value in metrics.items():
            for factor in (1 + regression, 1 - regression):
                moved = {case: {metric: value * factor}}
                assert off_gate(moved, {case: {metric: value}}), (case, metric, value, factor)


def inside_overlap(gt):
    """Ground truth ``gt`` (H x W, px) without the pixels whose match lies outside the right image (``x - d < 0``):
    no matcher can find those, and riverbed leaves them invalid unless LiDAR covers them (matching/overlap.py)."""
    import numpy as np

    x = np.arange(gt.shape[1])[None, :]
    with np.errstate(invalid="ignore"):
        return np.where(x - gt >= 0, gt, np.nan)
