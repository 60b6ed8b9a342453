"""The beamformer of :mod:`holodata.radar.beamform` in torch, for ``device="cuda"`` (any torch device;
``"cpu-torch"`` runs it on the CPU, which is how the tests compare it with the numpy path).

Same two formulations: at rest, FFTs along the chirp axis (correlation with the azimuth kernel);
moving, the direct sum over the window with the motion phase advanced one chirp at a time, here
batched over every elevation row at once (one kernel launch per chirp of the window, not per row).
Geometry (windows, compensations, column weights) comes from :mod:`.beam_geometry`, so both paths form
the same beams; complex64 throughout, phases reduced modulo 2π in float64 before they are cast.
"""
from __future__ import annotations

import numpy as np

from ._steps import Setup
from .beam_geometry import _REANCHOR, _to_columns, azimuth_kernel, motion_phase_rate, range_weights, vertical_weights, window


def _device(torch, device: str):
    return torch.device("cpu" if device in ("cpu-torch", "torch") else device)


def _polar(torch, phase: np.ndarray, dev):
    ph = torch.as_tensor(np.mod(phase, 2 * np.pi).astype(np.float32), device=dev)
    return torch.polar(torch.ones_like(ph), ph)


def beamform_torch(xp: np.ndarray, off: int, circular: bool, N: int, chirp, params, motion, device: str) -> np.ndarray:
    """(n_range, H, W) float32 from the padded, reflection-removed chirps ``xp`` (L, V, S) — see
    :func:`holodata.radar.beamform.beamform`, which prepares the arguments."""
    import torch

    dev = _device(torch, device)
    c64 = torch.complex64
    st = Setup.of(chirp, params, N)
    S, R, elev, H, beams, cw = st.S, st.R, st.elev, st.H, st.beams, st.cw
    n_syn = params.syn_count(N)
    h = (n_syn - 1) // 2
    vw = torch.as_tensor(vertical_weights(chirp, elev).transpose(2, 1, 0).astype(np.complex64), device=dev)  # (S,V,H)
    rw = torch.as_tensor(range_weights(chirp, params).astype(np.complex64), device=dev)
    K = azimuth_kernel(chirp, params, np.cos(elev), N).astype(np.complex64)       # (H, n_syn, S)
    b_t = torch.as_tensor(beams, device=dev)
    with torch.no_grad():
        x = torch.as_tensor(np.ascontiguousarray(xp), dtype=c64, device=dev)      # (L, V, S)
        if motion is None:
            Lf, _ = st.fft_plan(x.shape[0], off, circular)
            g = torch.zeros((S, Lf, H), dtype=c64, device=dev)
            idx = torch.as_tensor((-np.arange(-h, h + 1)) % Lf, device=dev)
            g[:, idx, :] = torch.as_tensor(K.transpose(2, 1, 0).copy(), device=dev)
            Kf = torch.fft.fft(g, dim=1)
            del g
            xf = torch.fft.fft(x, n=Lf, dim=0).permute(2, 0, 1).contiguous()        # (S, Lf, V)
            mag = torch.empty((R, H, beams.size), dtype=torch.float32, device=dev)
            blk = 16
            for a in range(0, H, blk):
                sl = slice(a, min(a + blk, H))
                Y = torch.matmul(xf, vw[:, :, sl]) * Kf[:, :, sl]
                y = torch.fft.ifft(Y, dim=1)[:, off + b_t, :] * rw[:, None, None]
                z = torch.fft.fft(y, dim=0)[:R]
                mag[:, sl, :] = z.abs().permute(0, 2, 1)
        else:
            if circular and h:
                x = torch.cat([x[N - h:], x, x[:h]], dim=0)
                off = h
            X = torch.matmul(x.permute(2, 0, 1), vw).permute(2, 1, 0).contiguous()  # (H, L, S)
            Kt = torch.as_tensor(K, device=dev)
            gam = np.stack([motion_phase_rate(chirp, params, motion, float(np.cos(e)), beams, N) for e in elev])
            Q = _polar(torch, gam, dev)                                              # (H, nb, S)
            wc = window(params.chirp_window, n_syn)
            acc = torch.zeros((H, beams.size, S), dtype=c64, device=dev)
            E = None
            for t, m in enumerate(range(-h, h + 1)):
                if t % _REANCHOR == 0 or E is None:
                    E = _polar(torch, gam * m, dev)
                if wc[t] != 0:
                    acc += X[:, off + b_t + m, :] * (E * Kt[:, t, None, :])
                E = E * Q
            if params.motion_reference == "rotation_start":
                acc *= _polar(torch, gam * beams[None, :, None], dev)
            z = torch.fft.fft(acc * rw, dim=2)[..., :R]                              # (H, nb, R)
            mag = z.abs().permute(2, 0, 1)
        out = mag.float().cpu().numpy()
    return _to_columns(out, cw)
