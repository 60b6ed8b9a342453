"""Register keeps a person who lingers at the far end of a walk along the camera's line of sight
(issue 23, point 4): the static depth leaves those pixels out and the LiDAR map's copy of the person
there explains nothing away (:func:`camera_swept`)."""
from __future__ import annotations

import numpy as np

# the held-out robot camera: stereo noise sigma = A z^2 (13 cm at 6 m), 3 round trips in 60 frames
A = 0.0037
F, H, W = 60, 24, 32
NEAR, FAR, WALL = 4.3, 6.4, 8.5
K = np.array([[40.0, 0, (W - 1) / 2], [0, 40.0, (H - 1) / 2], [0, 0, 1]])
PERSON = (slice(7, 17), slice(11, 21))


def _walk_stack(seed: int) -> np.ndarray:
    """(F,H,W) float32 depth images: a wall at WALL m, and a person walking back and forth between NEAR
    and FAR m along the line of sight who covers the PERSON pixels in every frame (the held-out robot
    camera's case: ~40 % of the frames within the background window of the far end, where the
    person turns)."""
    rng = np.random.default_rng(seed)
    phase = (np.arange(F) / F * 3.0) % 1.0
    walk = NEAR + (FAR - NEAR) * (1 - np.abs(phase * 2 - 1))    # NEAR -> FAR -> NEAR, three times
    depth = np.full((F, H, W), WALL)
    depth[:, PERSON[0], PERSON[1]] = walk[:, None, None]
    return (depth + A * depth ** 2 * rng.standard_normal(depth.shape)).astype(np.float32)


def test_the_far_end_of_a_walk_along_the_view_is_no_static_depth():
    """The pixels the person covers in every frame get no static depth: the background window around
    the far sample (3 sigma of the stereo model) holds ~40 % of the frames, spread evenly over it, and
    3 robust sigmas of such samples reach beyond the window; counting those as background made the
    lingering person static scene (the old code: most of those pixels had a static depth). The wall
    around keeps its depth."""
    from holodata.mapping.register import static_depth_of

    for seed in range(3):
        stack = _walk_stack(seed)
        far_end = stack[:, PERSON[0], PERSON[1]] >= FAR - 2 * 3 * A * FAR ** 2   # (the window around the far sample)
        assert 0.3 <= far_end.mean() < 0.5           # the far end holds a large minority of the frames
        mean, _, _ = static_depth_of(stack)
        assert np.isnan(mean[PERSON]).mean() >= 0.95
        wall = np.ones((H, W), bool)
        wall[PERSON] = False
        assert np.all(np.abs(mean[wall] - WALL) < 5 * A * WALL ** 2 / np.sqrt(F))    # (5 standard errors)


def test_the_map_copy_of_a_lingering_person_is_swept():
    """slam's map holds the person at the far end of the walk (the LiDAR never sees through it): those
    map points lie on pixels the walk sweeps, so they are carved; the wall behind (never seen on those
    pixels), the wall beside and a map point in front of the wall elsewhere are not. With the far end
    as static depth (the old code's) nothing is swept, and the map explained the person away."""
    from holodata.mapping.register import camera_swept, static_depth_of

    stack = _walk_stack(4)
    mean, _, _ = static_depth_of(stack)

    def at(v, u, z):
        return np.array([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z])

    ghost = np.array([at(v, u, z) for v in range(8, 16) for u in range(12, 20) for z in (FAR - 0.8, FAR - 0.2)])
    behind = np.array([at(v, u, WALL) for v in range(8, 16) for u in range(12, 20)])
    beside = np.array([at(v, u, WALL) for v in (2, 20) for u in (3, 28)])
    T = np.eye(4)
    images = list(stack)
    got = camera_swept(np.concatenate([ghost, behind, beside]), T, K, (H, W), images, mean)
    n = len(ghost)
    assert got[:n].all()
    assert not got[n:].any()
    still = np.where(np.isnan(mean), np.float32(FAR), mean)         # the far end taken for static scene
    assert not camera_swept(ghost, T, K, (H, W), images, still).any()
    # a frame without returns on most of the pixels (fewer than half the frames see them): not swept
    sparse = [np.where(np.arange(H)[:, None] < 12, np.nan, D).astype(np.float32) if k % 3 else D
              for k, D in enumerate(images)]
    assert not camera_swept(ghost[:16], T, K, (H, W), sparse, mean).any()
