"""A corridor point cloud for the registration tests (not a test module)."""
import numpy as np


def corridor(rng: np.random.Generator, n: int = 20000) -> np.ndarray:
    """(n,3) m: a corridor along x, walls y = ±1, floor z = 0, ceiling z = 2.5, no end wall: the view
    along it cannot tell where along x it is."""
    x = rng.uniform(0.0, 6.0, n)
    s = rng.uniform(0.0, 1.0, n)
    side = rng.integers(0, 4, n)
    return np.where(side[:, None] == 0, np.c_[x, -np.ones(n), 2.5 * s],
                    np.where(side[:, None] == 1, np.c_[x, np.ones(n), 2.5 * s],
                             np.where(side[:, None] == 2, np.c_[x, 2 * s - 1, np.zeros(n)],
                                      np.c_[x, 2 * s - 1, np.full(n, 2.5)])))
