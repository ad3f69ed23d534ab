"""Shared samplers for the geometry tests: uniform rotations plus the hard cases.

Near-identity and near-pi rotations exercise the small-angle and antipodal branches of
`so3.exp`, `so3.log` and `quat.from_matrix`; exactly pi about a general axis is included.
"""

from __future__ import annotations

import numpy as np


def unit_vectors(rng: np.random.Generator, n: int) -> np.ndarray:
    v = rng.standard_normal((n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def rotation_vectors(rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 3) rotation vectors with angles in [0, pi]: uniform, tiny, near pi and exactly pi."""
    axes = unit_vectors(rng, n)
    k = n // 6
    angles = np.concatenate(
        [
            rng.uniform(0.0, np.pi, n - 5 * k),
            10.0 ** rng.uniform(-12, -3, k),  # near identity
            np.pi - 10.0 ** rng.uniform(-12, -3, k),  # near pi
            np.full(k, np.pi),  # exactly pi
            np.zeros(k),  # identity
            rng.uniform(0.0, 1e-7, k),
        ]
    )
    return axes * angles[:, None]


def quaternions(rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 4) unit quaternions [x, y, z, w], both signs, including w = 0 and w = +-1."""
    q = rng.standard_normal((n, 4))
    q[: n // 8, 3] = 0.0  # rotations by pi
    q[n // 8 : n // 4, :3] *= 1e-9  # near identity
    return q / np.linalg.norm(q, axis=1, keepdims=True)
