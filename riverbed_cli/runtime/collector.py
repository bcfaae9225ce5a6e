"""Python's cyclic garbage collector in a ``riverbed`` process: off while a command starts up, and not tracing the
process's objects again when it exits.

A fresh ``riverbed match`` of the 740 x 500 speed pair took about 0.7 s of wall time for 0.02 s of matching. Two
parts of it were the collector's, not riverbed's:

* **At exit** the interpreter collects garbage while it tears its modules down, tracing every object still alive:
  Numba's, NumPy's, rasterio's and OpenCV's modules, hundreds of thousands of objects. That took 0.12-0.18 s,
  longer than the whole match (perf: the exit's samples were nearly all ``gc_collect_main``).
  :func:`freeze_for_exit` moves them to the collector's permanent generation first (``gc.freeze``), which it does
  not trace. Everything else of the exit stays: ``atexit`` handlers (logging, dask, temporary files), and
  every object freed by reference counting as its module is cleared. Only cycles alive at exit are left to the
  operating system, which takes the whole process's memory back anyway.
* **While it starts up** a command imports Numba, rasterio, OpenCV and riverbed (and ``riverbed match`` loads its
  kernels): allocations that trigger collections of objects that all stay alive. :func:`pause_for_start_up` (at
  the program's start) turns the collector off for that time, and :func:`start_up_done` freezes what start-up made
  and turns it on again, so that the command's own collections trace only its own objects: once the command's
  module is imported (``cli.main.RiverbedGroup``), or for ``riverbed match``, which imports the matching stack when
  it runs, once its kernels are loaded (``scale/match_files.py``).

Measured (fresh processes of the speed pair's ``--paths 4 --fusion none`` match, five alternating rounds): 0.67-0.72 s
wall as before, 0.57-0.63 s frozen at exit only, 0.55-0.58 s with the start-up pause as well (docs/tubes.md). The
garbage start-up leaves in cycles stays frozen (as ``gc.freeze``'s documentation has it for a process that forks):
the fused default's peak RSS on that pair 295.3-296.0 MB against 294.0-294.6 MB.

Only for the program (:func:`program`, the ``riverbed`` console script and ``python -m riverbed_cli``): a program
that imports riverbed, or a test that invokes the command in its own process (click's ``CliRunner``), keeps its
collector as it is. ``RIVERBED_GC=default`` in the environment leaves the collector alone in the program too.
"""

import contextlib
import gc
import os

_STATE = {"program": False, "paused": False}


@contextlib.contextmanager
def program():
    """The ``riverbed`` program's run: :func:`pause_for_start_up` and :func:`start_up_done` act inside it, and the
    objects alive when it ends (normally or by an error) are frozen for the exit (:func:`freeze_for_exit`)."""
    _STATE["program"] = os.environ.get("RIVERBED_GC", "") != "default"
    try:
        yield
    finally:
        freeze_for_exit()


def pause_for_start_up():
    """Turn the collector off until :func:`start_up_done`, in the program only and if it is on. Returns True when
    paused."""
    if not _STATE["program"] or _STATE["paused"] or not gc.isenabled():
        return False
    gc.disable()
    _STATE["paused"] = True
    return True


def start_up_done():
    """After :func:`pause_for_start_up`: freeze the objects start-up made (the collector no longer traces them) and
    turn the collector on again. Does nothing otherwise (the library calls it in any process)."""
    if not _STATE["paused"]:
        return
    _STATE["paused"] = False
    gc.freeze()
    gc.enable()


def freeze_for_exit():
    """In the program: move every object alive to the collector's permanent generation, so that the interpreter's
    exit does not trace them (``gc.freeze``). The collector is left on or off as it is."""
    if _STATE["program"]:
        gc.freeze()
