"""The fusion's helper thread: a function run beside the matcher (:class:`Beside`) or, where a thread would not pay,
when its result is asked for (:class:`After`), behind one interface.

The matcher's kernels use Numba's OpenMP workers; the thread runs NumPy/OpenCV work (the fusion's LiDAR side) that
releases the GIL. For it to find a core, the workers sleep between parallel regions (:mod:`.openmp`).
"""

import threading


class Beside(threading.Thread):
    """``fn(*args)`` in a thread, started at once; :meth:`result` waits for it and returns its value or raises its
    exception."""

    def __init__(self, fn, *args):
        super().__init__(daemon=True, name="riverbed-beside")
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


class After:
    """``fn(*args)`` run when :meth:`result` is called (the :class:`Beside` interface, no thread)."""

    def __init__(self, fn, *args):
        self._call = (fn, args)

    def result(self):
        fn, args = self._call
        return fn(*args)

    def join(self):
        pass
