"""The hostile-input fuzzer's fast sample (issue 24 §3; benchmarks/fuzz_hostile.py runs 1,000+
cases on demand): grammar-level TOML mutations, generated STL and schedule files, the flag
space and damaged --restart folders, each case one contracted exit with at most one line,
no traceback, no more than 2 GiB."""
from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import fuzz_hostile  # noqa: E402

N = 48


@pytest.fixture(scope="module")
def outcomes():
    return fuzz_hostile.fast_sample(N, seed=0)


def test_every_sampled_case_keeps_the_contract(outcomes):
    bad = [r for r in outcomes if r["problems"]]
    assert not bad, bad


def test_the_sample_covers_every_kind_and_both_outcomes(outcomes):
    """A sample that only ever refused (or only ran) would test half the contract."""
    kinds = {r["kind"] for r in outcomes}
    assert kinds >= {"scene", "stl", "schedule", "flags", "restart"}, kinds
    rcs = {r["rc"] for r in outcomes}
    assert 0 in rcs and 2 in rcs, rcs


def test_cases_are_reproducible():
    a, b = fuzz_hostile.case(0, 17), fuzz_hostile.case(0, 17)
    assert a == b and fuzz_hostile.case(1, 17) != a
