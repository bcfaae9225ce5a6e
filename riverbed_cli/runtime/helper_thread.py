"""The fusion's helper thread: a function run in a thread beside the matcher (:class:`InThread`) or, where a thread
would not pay, when its result is asked for (:class:`OnDemand`), behind one interface.

The matcher's kernels use Numba's OpenMP workers; the thread runs NumPy/OpenCV work (the fusion's LiDAR side) that
releases the GIL. For it to find a core, the workers sleep between parallel regions (:mod:`.openmp`).
"""

import threading


class InThread(threading.Thread):
    """``fn(*args)`` in a thread, started at once; :meth:`result` waits for it and returns its value or raises its
    exception."""

    def __init__(self, fn, *args):
        super().__init__(daemon=True, name="riverbed-helper")
        self._call = (fn, args)
        self._value, self._error = None, None
        self.start()

    def run(self):
        fn, args = self._call
        try:
            self._value = fn(*args)
        except BaseException as e:  # handed to the caller of result()
            self._error = e

    def result(self):
        self.join()
        if self._error is not None:
            raise self._error
        return self._value


class OnDemand:
    """``fn(*args)`` run when :meth:`result` is called (the :class:`InThread` interface, no thread)."""

    def __init__(self, fn, *args):
        self._call = (fn, args)

    def result(self):
        fn, args = self._call
        return fn(*args)

    def join(self):
        pass
