import os

# Each pytest-xdist worker runs its numba kernels on one thread: the README's `-n 2` already
# puts one worker on each of CI's two cores, and a worker's second numba thread only contends
# with the other worker. Set before numba is imported (numba reads it once); a value already
# in the environment is kept.
if os.environ.get("PYTEST_XDIST_WORKER"):
    os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import pytest  # noqa: E402

EXAMPLES = os.path.join(os.path.dirname(__file__), "..", "examples")


def example(name: str) -> str:
    return os.path.abspath(os.path.join(EXAMPLES, name))


@pytest.fixture
def examples_dir():
    return os.path.abspath(EXAMPLES)


# The README runs the suite as `pytest -n 2 --dist loadfile`: each file goes whole to the next
# free worker, in collection order. Files collected alphabetically put the longest ones
# (numba's CUDA simulator, the wave flume) wherever the alphabet does, and one worker can
# be left with a long file while the other idles. Longest first (seconds of a 2-core run,
# 2026-12-04, summed over each file's tests) lets the two workers end together.
LONGEST_FIRST = ("test_cuda_mdbc_ranks.py", "test_cuda_multirank.py", "test_waves.py", "test_cuda_backend.py",
                 "test_probe_sums.py", "test_compute_conformance.py", "test_multirank.py", "test_cuda_dufort.py",
                 "test_cuda_riemann.py", "test_cuda_riemann_jump.py", "test_physics.py", "test_examples_baseline.py", "test_cuda_mdbc.py")


def pytest_collection_modifyitems(config, items):
    rank = {name: i for i, name in enumerate(LONGEST_FIRST)}
    order = {id(it): k for k, it in enumerate(items)}
    items.sort(key=lambda it: (rank.get(os.path.basename(str(it.fspath)), len(rank)), order[id(it)]))
