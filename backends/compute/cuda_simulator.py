"""numba's CUDA simulator (`NUMBA_ENABLE_CUDASIM=1`) with a block runner that waits instead of
polling: the same kernels, the same semantics, about twice as fast on our kernels.

The simulator runs each CUDA thread of a block as a Python thread. Its `BlockManager.run`
starts a new thread per CUDA thread and launch (`Thread.start` waits for each to begin), then
polls every live thread in a loop to find when all are blocked in `syncthreads`; that loop
holds the GIL the threads need, and the block scans and reductions of cuda_sort / cuda_reduce
sync a dozen times a launch. Here:

* each position of a block is a *lane*, a persistent `BlockThread` that takes one CUDA
  thread's work after another (`threading.current_thread()` is the lane, so `threadIdx`,
  `blockIdx`, `syncthreads` and the warp helpers of the simulator's kernel API find it);
* `syncthreads` is a counting barrier on a condition variable: the last live thread to
  arrive releases the others, and a thread that ends counts as arrived for the rest (the
  simulator's rule: a barrier waits for the live threads only);
* an exception in one thread aborts the others at their next barrier and is raised from the
  launch, as the simulator does;
* a kernel whose threads never meet (no barrier, warp call or shared array in it or in
  what it calls: `_independent`) runs its block's threads one after the other on one lane,
  a hand-off per block instead of per thread (the element-wise kernels take a quarter of
  the time). A kernel that spun on a flag another thread of its block sets would hang
  there; none does;
* `cuda.shared.array` takes a lock: the simulator keys a block's shared array by the calling
  line and creates it on first use, and two threads preempted between its lookup and its
  store would each get an array of their own.

`install()` replaces those three methods of the simulator's classes; cuda_retarget calls it
when the simulator is on. Nothing changes on a GPU.
"""
from __future__ import annotations

import sys
import threading
import types

import numpy as np

_LANES: list = []
_LANES_LOCK = threading.Lock()


def _barrier(self):
    """BlockThread.syncthreads: wait until every live thread of the block has arrived."""
    if self.abort:
        raise RuntimeError("abort flag set on syncthreads call")
    m = self._manager
    with m._cv:
        gen = m._gen
        m._blocked += 1
        if m._blocked == m._live:
            m._blocked = 0
            m._gen += 1
            m._cv.notify_all()
        else:
            while m._gen == gen and not self.abort:
                m._cv.wait()
    if self.abort:
        raise RuntimeError("abort flag set on syncthreads clear")


def _finished(m, lane):
    """A lane's thread ended: count it out of the barrier; the first exception aborts the
    block; the launch returns when no thread is live."""
    with m._cv:
        m._live -= 1
        if lane.exception is not None and m._first is None:
            m._first = lane
            for t in m._lanes:
                t.abort = True
        elif m._live and m._blocked == m._live:    # the rest all wait: the barrier opens
            m._blocked = 0
            m._gen += 1
        elif m._live:       # nobody's wait ends here: waking them all costs a GIL hand-off each
            return
        m._cv.notify_all()


def _lane_class(K):
    class Lane(K.BlockThread):
        """One position of a block, reused by every launch (BlockThread's per-thread fields,
        set per job)."""

        def __init__(self):
            threading.Thread.__init__(self, daemon=True)
            self._go = threading.Semaphore(0)
            self._job = None
            self.syncthreads_event = threading.Event()
            self.syncthreads_blocked = False

        def assign(self, manager, block_point, thread_point, target):
            self._manager = manager
            self.blockIdx = K.Dim3(*block_point)
            self.at(thread_point)
            self.exception = None
            self.abort = False
            self.debug = manager._debug
            self._job = target

        def at(self, thread_point):
            """Be the CUDA thread at `thread_point` of the block."""
            self.threadIdx = K.Dim3(*thread_point)
            bd = self._manager._block_dim
            self.thread_id = thread_point[0] + bd[0] * (thread_point[1] + bd[1] * thread_point[2])

        def run(self):
            while True:
                self._go.acquire()
                try:
                    if self.debug:
                        np.seterr(divide="raise")
                    self._job()
                except Exception as e:  # noqa: BLE001 -- re-raised by the launch, as BlockThread does
                    msg = f"tid={list(self.threadIdx)} ctaid={list(self.blockIdx)}"
                    self.exception = (type(e)(f"{msg}: {e}" if str(e) else msg), sys.exc_info()[2])
                _finished(self._manager, self)

    return Lane


def _take_lanes(K, n):
    """n idle lanes (new ones started as needed): launches from several host threads at once
    (the mock ranks' collectives) each get their own."""
    with _LANES_LOCK:
        while len(_LANES) < n:
            lane = _CLASS.setdefault("lane", _lane_class(K))()
            lane.start()
            _LANES.append(lane)
        taken = _LANES[-n:]
        del _LANES[-n:]
        return taken


def _give_lanes(lanes):
    with _LANES_LOCK:
        _LANES.extend(lanes)


_CLASS: dict = {}


# the kernel API's calls through which a block's threads wait for, or read, each other
_SHARED_CALLS = frozenset({
    "syncthreads", "syncthreads_count", "syncthreads_and", "syncthreads_or", "syncwarp",
    "shfl_sync", "shfl_up_sync", "shfl_down_sync", "shfl_xor_sync", "all_sync", "any_sync",
    "eq_sync", "ballot_sync", "match_any_sync", "match_all_sync", "activemask", "cg", "shared"})
_INDEPENDENT: dict = {}


def names_in(code):
    """Every global or attribute name the code object reads, its nested functions' included."""
    yield from code.co_names
    for c in code.co_consts:
        if isinstance(c, types.CodeType):
            yield from names_in(c)


def _independent(f) -> bool:
    """Whether the kernel function `f` and every function it calls (plain copies, or the
    simulator's device wrappers) name none of _SHARED_CALLS: its threads never meet."""
    key = f.__code__
    if key not in _INDEPENDENT:
        _INDEPENDENT[key] = True        # a recursive call of itself names nothing new
        _INDEPENDENT[key] = not _meets(f)
    return _INDEPENDENT[key]


def _meets(f) -> bool:
    names = set(names_in(f.__code__))
    if _SHARED_CALLS & names:
        return True
    g = f.__globals__
    callees = (getattr(g.get(n), "fn", g.get(n)) for n in names)     # a device wrapper's function
    return any(isinstance(v, types.FunctionType) and not _independent(v) for v in callees)


def _make_run(K):
    def run(self, grid_point, *args):
        """BlockManager.run: the block's threads on the lanes; returns when all have ended."""
        f = self._f
        points = list(np.ndindex(*self._block_dim))
        if _independent(f):
            # no thread of the block waits for another: one lane runs them one after the
            # other (one order a GPU may run them in), a hand-off per block, not per thread
            def target():
                for tp in points:
                    lanes[0].at(tp)
                    f(*args)
            lanes = _take_lanes(K, 1)
        else:
            def target():
                f(*args)
            lanes = _take_lanes(K, len(points))
        self._lanes = lanes
        self._cv = threading.Condition()
        self._live, self._blocked, self._gen, self._first = len(lanes), 0, 0, None
        for lane, tp in zip(lanes, points):
            lane.assign(self, grid_point, tp, target)
        for lane in lanes:
            lane._go.release()
        with self._cv:
            while self._live:
                self._cv.wait()
        _give_lanes(lanes)
        bad = self._first or next((t for t in lanes if t.exception), None)
        if bad is not None:
            raise bad.exception[0].with_traceback(bad.exception[1])
    return run


def _shared_array(lock):
    from numba.core import types
    from numba.np import numpy_support

    def array(self, shape, dtype):
        """FakeCUDAShared.array under a lock (the simulator's code otherwise: one array per
        calling line and launch; dynamic shared memory for shape 0)."""
        if isinstance(dtype, types.Type):
            dtype = numpy_support.as_dtype(dtype)
        if shape == 0:
            count = self._dynshared_size // dtype.itemsize
            return np.frombuffer(self._dynshared.data, dtype=dtype, count=count)
        f = sys._getframe(1)
        caller = (f.f_code.co_filename, f.f_lineno)
        with lock:
            res = self._allocations.get(caller)
            if res is None:
                res = np.empty(shape, dtype)
                self._allocations[caller] = res
        return res
    return array


def install() -> None:
    """Put the waiting block runner into numba's simulator (once)."""
    from numba.cuda.simulator import kernel as K
    from numba.cuda.simulator import kernelapi as KA
    if getattr(K.BlockManager.run, "_sphgraph", False):
        return
    run = _make_run(K)
    run._sphgraph = True
    K.BlockThread.syncthreads = _barrier
    K.BlockManager.run = run
    KA.FakeCUDAShared.array = _shared_array(threading.Lock())
