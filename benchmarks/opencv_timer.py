"""Times OpenCV StereoSGBM in a process of its own, as a user's program runs it.

The benchmarks that compare riverbed with OpenCV run riverbed with the ``riverbed`` command's process settings
(``import riverbed_cli.cli``: glibc keeps freed memory instead of returning it, NumPy's huge pages off). Those settings
also speed up OpenCV when it runs in the same process: each ``compute()`` then reuses the freed buffers of the last
one instead of faulting in fresh pages. Measured on the 740 x 500 speed pair and the 1024 x 1024 aerial pair (fresh
processes, medians of 5 warm calls): MODE_HH 0.068-0.092 / 0.49-0.54 s with them against 0.12-0.16 / 0.74-0.85 s
without; SGBM_3WAY about the same either way. So OpenCV is timed here, in a process that imports only OpenCV and
NumPy.

Usage: ``python opencv_timer.py LEFT RIGHT MIN_DISP NUM_DISP MODE[,MODE...] [REPEAT]`` with 8-bit grey images
(read unchanged) and modes named as OpenCV's (``HH``, ``SGBM_3WAY``, ``SGBM``, ``HH4``). Each mode gets one warm-up
``compute()`` (its allocations), then ``REPEAT`` (default 1) timed ones. Prints ``{"HH": [seconds, ...], ...}`` as
JSON on stdout. The penalties are :func:`bench_match.opencv_sgbm`'s (block size 5, ``P1 = 8 * 25``, ``P2 = 32 * 25``).
"""

import json
import sys
import time

import cv2


def main(argv):
    left, right, d_min, num, modes = argv[:5]
    repeat = int(argv[5]) if len(argv) > 5 else 1
    gl = cv2.imread(left, cv2.IMREAD_UNCHANGED)
    gr = cv2.imread(right, cv2.IMREAD_UNCHANGED)
    if gl is None or gr is None:
        sys.exit(f"opencv_timer: cannot read {left if gl is None else right}")
    bs = 5
    out = {}
    for name in modes.split(","):
        sgbm = cv2.StereoSGBM_create(minDisparity=int(d_min), numDisparities=int(num), blockSize=bs,
                                     P1=8 * bs * bs, P2=32 * bs * bs, mode=getattr(cv2, f"STEREO_SGBM_MODE_{name}"))
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
