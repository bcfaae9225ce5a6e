"""Rows of a raster-order pass handed between threads: SGM's passes (:func:`..sgm_pass.sgm_rows`) and AD-Census's
scanline passes (:mod:`..adcensus.scanline`).

A pass's path costs at a pixel depend on the row before (and two before, for 16 SGM paths) near the same column, so
a pass runs on several threads as a pipeline: each thread takes the next row from a counter (:func:`next_row`)
and sweeps it in blocks (:func:`block_size`), each block once the rows before have done the pixels it reads
(:func:`block_end`), publishing how far it is after each block (:func:`publish`). A thread waits only for rows taken
before it by threads that are running, so a pass given more threads than run still ends. The split of a run's
threads between the two passes of a match is :func:`pass_threads`.
"""

import numpy as np

from ...runtime.kernel import kernel
from .atomics import fetch_add, load_acquire, store_release, yield_cpu

#: the most threads one pass runs on (twice this for the two passes)
MAX_PASS_THREADS = 8
#: on several threads a row is swept in blocks of at least this many pixels; a row is two blocks per thread of its
#: pass (fewer blocks, fewer waits; enough of them to keep every thread's row in flight)
BLOCK_MIN = 32
#: turns of a waiting loop before the thread yields its core at every turn (more threads than cores: the one it
#: waits for may be queued behind it)
SPINS = 200
#: progress per row PAD elements apart (a cache line): one row's thread writes it, the next rows' read it
PAD = 8


@kernel
def pass_threads(H, threads):
    """How many of a run's ``threads`` each of the two passes takes: half (the forward pass the odd one), at least
    one, at most :data:`MAX_PASS_THREADS` and a thread per row."""
    n = min(max(2, threads), 2 * MAX_PASS_THREADS)
    return max(1, min((n + 1) // 2, H)), max(1, min(n // 2, H))


@kernel
def new_progress(H, threads):
    """The pass's progress per row (pixels done), for several threads (empty for one)."""
    return np.zeros(H * PAD if threads > 1 else 0, np.int64)


@kernel(inline=True)
def block_size(W, threads):
    """The pixels of a block of a row of ``W`` on a pass of ``threads`` threads (the whole row on one)."""
    return W if threads == 1 else max(BLOCK_MIN, W // (2 * threads))


@kernel(inline=True)
def next_row(claim, progress, H, W, slots, reach, threads):
    """The next row of the pass (``claim``: its counter, one int64; ``H`` or more: none left). On several threads
    its ring-buffer slot (of ``slots``) is free first: the ``reach`` rows after the slot's last row, which read it,
    are done."""
    yy = fetch_add(claim, 0, 1)
    if yy < H and threads > 1:
        for r in range(yy - slots + 1, yy - slots + 1 + reach):
            wait_row_done(progress, r, W)
    return yy


@kernel(inline=True)
def spin(spins):
    """One more turn of a waiting loop: after :data:`SPINS` turns the thread yields its core at every turn."""
    if spins >= SPINS:
        yield_cpu()
        return spins
    return spins + 1


@kernel(inline=True)
def wait_row_done(progress, r, W):
    """Wait until row ``r`` (if any) has done all its ``W`` pixels."""
    spins = 0
    while r >= 0 and load_acquire(progress, r * PAD) < W:
        spins = spin(spins)


@kernel(inline=True)
def publish(progress, yy, done):
    """Row ``yy`` has done its first ``done`` pixels (every direction): a release store, after the path costs."""
    store_release(progress, yy * PAD, done)


@kernel(inline=True)
def block_end(progress, yy, b0, W, block, back1, back2):
    """The end of row ``yy``'s next block from pixel ``b0`` on: at most ``block`` pixels, once the rows one and two
    before have done the pixels its steps read there (``back1``, ``back2``: the least ``dx`` of the directions that
    reach them, a step at ``x`` reading ``x - dx``; ``W`` for none), waiting until they have done at least one."""
    spins = 0
    while True:
        end = min(W, b0 + block)
        if yy >= 1 and back1 < W:
            a = load_acquire(progress, (yy - 1) * PAD)
            if a < W:
                end = min(end, a + back1)
        if yy >= 2 and back2 < W:
            a = load_acquire(progress, (yy - 2) * PAD)
            if a < W:
                end = min(end, a + back2)
        if end > b0:
            return end
        spins = spin(spins)
