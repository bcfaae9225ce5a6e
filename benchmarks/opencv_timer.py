"""Times OpenCV StereoSGBM in a process of its own, as a user's program runs it.

The benchmarks that compare riverbed with OpenCV run riverbed with the ``riverbed`` command's process settings
(``riverbed_cli.runtime.Env``: glibc keeps freed memory instead of returning it, NumPy's huge pages off). Those settings
also speed up OpenCV when it runs in the same process: each ``compute()`` then reuses the freed buffers of the last
one instead of faulting in fresh pages. Measured on the 740 x 500 speed pair and the 1024 x 1024 aerial pair (fresh
processes, medians of 5 warm calls): MODE_HH 0.068-0.092 / 0.49-0.54 s with them against 0.12-0.16 / 0.74-0.85 s
without; SGBM_3WAY about the same either way. So OpenCV is timed here, in a process that imports only OpenCV and
NumPy.

Usage: ``python opencv_timer.py LEFT RIGHT MIN_DISP NUM_DISP MODE[,MODE...] [REPEAT]`` with 8-bit grey images
(read unchanged) and modes named as OpenCV's (``HH``, ``SGBM_3WAY``, ``SGBM``, ``HH4``). Each mode gets one warm-up
``compute()`` (its allocations), then ``REPEAT`` (default 1) timed ones. Prints ``{"HH": [seconds, ...], ...}`` as
JSON on stdout. :func:`create_sgbm` sets the penalties (:func:`bench_match.opencv_sgbm` uses it too).
"""

import json
import math
import sys
import time

import cv2


def num_disparities(d_min, d_max):
    """OpenCV's ``numDisparities`` for the range ``[d_min, d_max]``: its width rounded up to a multiple of 16."""
    return int(math.ceil((d_max - d_min + 1) / 16.0) * 16)


def create_sgbm(d_min, num, mode):
    """StereoSGBM with the usual block-size-5 penalties (``mode`` an OpenCV ``STEREO_SGBM_MODE_*`` constant)."""
    bs = 5
    return cv2.StereoSGBM_create(minDisparity=int(d_min), numDisparities=int(num), blockSize=bs, P1=8 * bs * bs,
                                 P2=32 * bs * bs, mode=mode)


def main(argv):
    left, right, d_min, num, modes = argv[:5]
    repeat = int(argv[5]) if len(argv) > 5 else 1
    gl = cv2.imread(left, cv2.IMREAD_UNCHANGED)
    gr = cv2.imread(right, cv2.IMREAD_UNCHANGED)
    if gl is None or gr is None:
        sys.exit(f"opencv_timer: cannot read {left if gl is None else right}")
    out = {}
    for name in modes.split(","):
        sgbm = create_sgbm(d_min, num, getattr(cv2, f"STEREO_SGBM_MODE_{name}"))
        sgbm.compute(gl, gr)  # warm-up (allocations)
        times = []
        for _ in range(repeat):
            t = time.perf_counter()
            sgbm.compute(gl, gr)
            times.append(time.perf_counter() - t)
        out[name] = times
    print(json.dumps(out))


if __name__ == "__main__":
    main(sys.argv[1:])
