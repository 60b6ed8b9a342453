"""The report's PNG figures (matplotlib, Agg backend), sized to be read at 1280 px: every figure is
about 1170 px wide (shown at its natural size in the report's 1200 px column) and keeps its
legend outside the axes."""
from __future__ import annotations

import contextlib
import json
import math
from pathlib import Path

import numpy as np

from holodata.metrics import HUMAN_MATCH_M

COLORS = {"gt": "0.25", "model": "tab:blue", "baseline": "tab:orange", "model_no_refine": "tab:cyan",
          "model_analytic": "tab:brown", "oracle_stage1": "tab:olive"}
BEV_ORDER = ("gt", "model", "model_no_refine", "model_analytic", "baseline", "oracle_stage1")
DPI = 90
WIDTH_IN = 13.0          # 13 in × 90 dpi = 1170 px: the report's column at 1280 px
METRIC_STYLES = (("precision", ":"), ("recall", "--"), ("f_score", "-"))


def _plt():
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: Path, plt) -> None:
    fig.savefig(path, dpi=DPI)
    plt.close(fig)


def _method_legend(fig, methods, styles=None, title=None):
    """One legend right of the axes: a colour per method (+ a line style per curve kind)."""
    from matplotlib.lines import Line2D

    h = [Line2D([], [], color=COLORS.get(m, "k"), lw=2) for m in methods]
    lab = list(methods)
    if styles:
        h += [Line2D([], [], color="0.3", ls=ls) for _, ls in styles]
        lab += [k.replace("_", "-") for k, _ in styles]
    fig.legend(h, lab, loc="center left", bbox_to_anchor=(0.83, 0.5), frameon=False, title=title, fontsize=10)


def fig_hidden_side(path: Path, fr: dict, method: str = "model") -> None:
    """One held-out frame from above (x–y, radar frame): GT and predicted LOS / NLOS points, the
    person (GT human returns, true and predicted centres), the radar; legend outside the axes."""
    plt = _plt()
    from matplotlib.lines import Line2D

    fig, ax = plt.subplots(figsize=(WIDTH_IN, 8.4), layout="constrained")
    gt, pr = fr["gt"], fr["pred"]
    # drawn bottom to top: the ground truth of the hidden side and the person stay visible above the prediction
    layers = [
        ("gt_los", gt["los"], dict(s=5, c="0.72", marker="o", lw=0, zorder=1), "ground truth LOS (seen directly)"),
        ("gt_nlos", gt["nlos"], dict(s=16, c="#7e57c2", marker="o", lw=0, zorder=3),
         "ground truth NLOS (the hidden side)"),
        ("gt_human", gt["human"], dict(s=22, c="#ff9800", marker="o", lw=0, zorder=3.5), "ground truth person returns"),
        ("pred_los", pr["los"], dict(s=5, c="tab:green", marker="o", lw=0, zorder=1.5), f"{method} LOS"),
        ("pred_nlos", pr["nlos"], dict(s=16, c="tab:red", marker="x", lw=0.8, alpha=0.6, zorder=2), f"{method} NLOS"),
    ]
    counts = fr.get("counts") or {}
    handles, labels = [], []
    for key, p, kw, label in layers:
        p = np.asarray(p).reshape(-1, 3)
        ax.scatter(p[:, 0], p[:, 1], rasterized=True, **kw)
        handles.append(Line2D([], [], ls="none", marker=kw["marker"], c=kw["c"], ms=8, mew=1.5))
        labels.append(f"{label} ({counts.get(key, len(p))})")
    t = np.asarray(fr["gt_centres"]).reshape(-1, 3)
    q = np.asarray(fr["pred_centres"]).reshape(-1, 3)
    ax.scatter(t[:, 0], t[:, 1], s=420, marker="*", c="gold", edgecolors="k", linewidths=1.2, zorder=5)
    for c in t:
        ax.add_patch(plt.Circle((c[0], c[1]), HUMAN_MATCH_M, fill=False, ls="--", lw=1, ec="0.3", zorder=4))
    ax.scatter(q[:, 0], q[:, 1], s=260, marker="X", c="tab:blue", edgecolors="k", linewidths=1.2, zorder=6)
    ax.plot([0], [0], marker="^", ms=14, c="k", ls="none", zorder=7)
    handles += [Line2D([], [], ls="none", marker="*", ms=16, mfc="gold", mec="k"),
                Line2D([], [], ls="none", marker="X", ms=12, mfc="tab:blue", mec="k"),
                Line2D([], [], ls="none", marker="^", ms=11, c="k"),
                Line2D([], [], ls="--", c="0.3", lw=1)]
    labels += [f"person, true centre ({len(t)})", f"person, {method} centre ({len(q)})", "radar",
               f"{HUMAN_MATCH_M * 100:.0f} cm match radius"]
    ax.margins(0.05)
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(alpha=0.3)
    ax.set_xlabel("x (m, radar frame)", fontsize=12)
    ax.set_ylabel("y (m, radar frame)", fontsize=12)
    if fr.get("hidden_person"):
        person = "hidden (seen only through bounces)" + ("" if len(t) else ", too few returns for a centre")
    else:
        person = "in sight" if len(t) else "none in the ground truth"
    f = fr.get("nlos_f_score")
    # two lines: on one the title ran past the axes into the legend beside them
    ax.set_title(f"scene {fr['scene']}, frame {fr['frame']}"
                 + ("" if f is None or not math.isfinite(f) else f": {method} NLOS F-score {f * 100:.1f} %")
                 + f"\nperson {person}", fontsize=13, loc="left")
    fig.legend(handles, labels, loc="outside right upper", fontsize=11, frameon=False)
    _save(fig, path, plt)


def fig_range_images(path: Path, ex: dict, max_range: float) -> None:
    plt = _plt()
    cols = ("gt", "model", "baseline")
    fig, axes = plt.subplots(3, 3, figsize=(WIDTH_IN, 6.5), squeeze=False)
    for b in range(3):
        for c, name in enumerate(cols):
            ax = axes[b, c]
            img = np.ma.masked_invalid(ex[name][b])
            im = ax.imshow(img, vmin=0, vmax=max_range, cmap="viridis", aspect="auto", interpolation="nearest")
            ax.set_title(f"bounce {b + 1}: {'ground truth' if name == 'gt' else name}", fontsize=10)
            ax.set_xticks([])
            ax.set_yticks([])
    fig.colorbar(im, ax=axes, shrink=0.8, label="range R_b (m)")
    fig.suptitle(f"scene {ex['scene']}, frame {ex['frame']} (white = no return)")
    _save(fig, path, plt)


def fig_error_cdf(path: Path, errs: dict) -> None:
    plt = _plt()
    fig, axes = plt.subplots(1, 3, figsize=(WIDTH_IN, 4.0), sharey=True)
    for b in range(3):
        ax = axes[b]
        for m, e in errs.items():
            e = np.sort(np.asarray(e[b])) * 100
            if e.size:
                ax.plot(e, np.arange(1, e.size + 1) / e.size, color=COLORS.get(m))
        ax.set_xscale("symlog", linthresh=1.0)
        ax.set_xlabel("absolute range error (cm)")
        ax.set_title(f"bounce {b + 1}")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("fraction of GT pixels")
    fig.tight_layout(rect=(0, 0, 0.82, 1))
    _method_legend(fig, list(errs))
    _save(fig, path, plt)


def fig_bev(path: Path, ex: dict) -> None:
    """Every row's clouds of the example frame from above, three panels a row, one legend on top."""
    plt = _plt()
    names = [n for n in BEV_ORDER if n in ex["clouds"]]
    ncol = min(3, len(names))
    nrow = math.ceil(len(names) / ncol)
    H = 3.9 * nrow + 1.3
    fig, axes = plt.subplots(nrow, ncol, figsize=(WIDTH_IN, H), sharex=True, sharey=True, squeeze=False)
    fig.subplots_adjust(left=0.06, right=0.99, top=1 - 1.0 / H, bottom=0.6 / H, wspace=0.12, hspace=0.25)
    for ax in axes.flat[len(names):]:
        ax.set_visible(False)
    for ax, name in zip(axes.flat, names):
        cl = ex["clouds"][name]
        n = {}
        for part, col in (("los", "tab:green"), ("nlos", "tab:purple")):
            p = np.asarray(cl[part]).reshape(-1, 3)
            n[part] = len(p)
            if len(p):
                ax.scatter(p[:, 0], p[:, 1], s=2, c=col, rasterized=True)
        ax.plot([0], [0], "k^", ms=8)
        ax.set_title(f"{'ground truth' if name == 'gt' else name}: LOS {n['los']}, NLOS {n['nlos']}", fontsize=11)
        ax.set_aspect("equal", adjustable="box")
        ax.grid(alpha=0.3)
    for ax in axes[-1]:
        ax.set_xlabel("x (m, radar frame)")
    for ax in axes[:, 0]:
        ax.set_ylabel("y (m)")
    from matplotlib.lines import Line2D

    h = [Line2D([], [], ls="none", marker="o", c=c, ms=7) for c in ("tab:green", "tab:purple")]
    h.append(Line2D([], [], ls="none", marker="^", c="k", ms=8))
    fig.suptitle(f"bird's-eye view, scene {ex['scene']} frame {ex['frame']}", fontsize=12, y=1 - 0.12 / H, va="top")
    fig.legend(h, ["LOS points", "NLOS points", "radar"], loc="upper center", bbox_to_anchor=(0.5, 1 - 0.42 / H),
               ncol=3, frameon=False, fontsize=11)
    _save(fig, path, plt)


def fig_prf(path: Path, doc: dict) -> None:
    plt = _plt()
    fig, axes = plt.subplots(1, 2, figsize=(WIDTH_IN, 4.4), sharey=True)
    for ax, part in zip(axes, ("los", "nlos")):
        for m, res in doc["methods"].items():
            c = res["prf_curve"][part]
            t = np.array(c["tau"]) * 100
            for key, ls in METRIC_STYLES:
                v = np.array([np.nan if x is None else x for x in c[key]], float)
                ax.plot(t, v, ls, color=COLORS.get(m))
        ax.axvline(doc["settings"]["tau_m"] * 100, color="0.6", lw=0.8)
        ax.set_xlabel("threshold τ (cm)")
        ax.set_title(f"{part.upper()} point cloud")
        ax.set_ylim(0, 1.02)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("precision / recall / F")
    fig.tight_layout(rect=(0, 0, 0.82, 1))
    _method_legend(fig, list(doc["methods"]), METRIC_STYLES)
    _save(fig, path, plt)


def fig_training(path: Path, log: Path) -> bool:
    rows = []
    for line in log.read_text().splitlines():
        with contextlib.suppress(ValueError):
            rows.append(json.loads(line))
    if not rows:
        return False
    plt = _plt()
    fig, ax = plt.subplots(figsize=(WIDTH_IN * 0.75, 3.8))
    ep = [r["epoch"] for r in rows]
    for key in ("loss", "l1", "grad", "valid", "human"):
        if key in rows[0]:
            ax.plot(ep, [r.get(key) for r in rows], label=key)
    ax.set_yscale("log")
    ax.set_xlabel("epoch")
    ax.set_ylabel("training loss")
    ax.grid(alpha=0.3)
    fig.tight_layout(rect=(0, 0, 0.82, 1))
    fig.legend(loc="center left", bbox_to_anchor=(0.83, 0.5), frameon=False)
    _save(fig, path, plt)
    return True
