"""A grid path reduced to its corners keeps its shape: same ends, every dropped point on a straight
run between kept ones."""
import numpy as np

from agents.services.planning import corners


def test_corners_keep_ends_and_turns_only():
    path = np.array([[0, 0], [1, 0], [2, 0], [3, 1], [4, 2], [4, 3], [4, 4], [4, 5]], float)
    assert corners(path).tolist() == [[0, 0], [2, 0], [4, 2], [4, 5]]
    assert corners(path[:2]).tolist() == path[:2].tolist()


def test_exact_ends_are_kept():
    path = np.array([[0.3, 0.2], [1, 0], [2, 0], [3, 0]], float)
    assert corners(path).tolist() == [[0.3, 0.2], [1, 0], [3, 0]]
