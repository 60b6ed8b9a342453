"""Tiny synthetic multi-return frames for the torch tests (not a test module)."""
import numpy as np


def synth_frames(T=8, H=16, W=64, n=32, dr=0.3, seed=0, noise=0.02):
    """heatmap (T,n,H,W) linear amplitude with a Gaussian bump at each GT range; gt range (T,3,H,W)
    metres (bounce 3 missing on a band of columns); label (T,3,H,W) with a 'human' patch."""
    rng = np.random.default_rng(seed)
    j = np.arange(W)[None, :]
    i = np.arange(H)[:, None]
    R = np.full((T, 3, H, W), np.nan, np.float32)
    L = np.zeros((T, 3, H, W), np.uint8)
    for t in range(T):
        ph = rng.uniform(0, 2 * np.pi)
        r1 = 2.0 + 1.0 * np.sin(2 * np.pi * j / W + ph) + 0.02 * i
        r2 = r1 + 2.0 + 0.5 * np.cos(4 * np.pi * j / W + ph)
        r3 = r2 + 1.5 + 0.0 * i
        R[t, 0], R[t, 1] = r1, r2
        R[t, 2] = np.where((j % W) < W // 2, r3, np.nan)
        L[t, 0] = 1
        L[t, 1] = 2
        L[t, 2] = np.where(np.isfinite(R[t, 2]), 2, 0)
        c = int(rng.integers(0, W - 8))
        L[t, 1, 4:10, c:c + 6] = 4
    centres = (np.arange(n) + 0.5) * dr
    amp = np.array([1.0, 0.3, 0.1])
    hm = noise * rng.random((T, n, H, W)).astype(np.float32)
    for b in range(3):
        r = np.nan_to_num(R[:, b], nan=-100.0)
        a = amp[b] * (1.0 + 2.0 * (L[:, b] == 4))[:, None]  # humans reflect more than walls here
        hm += a * np.exp(-0.5 * ((centres[None, :, None, None] - r[:, None]) / dr) ** 2)
    return hm.astype(np.float32), R, L
