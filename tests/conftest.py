import os

import pytest

EXAMPLES = os.path.join(os.path.dirname(__file__), "..", "examples")


def example(name: str) -> str:
    return os.path.abspath(os.path.join(EXAMPLES, name))


@pytest.fixture
def examples_dir():
    return os.path.abspath(EXAMPLES)
