"""report.html + PNG figures (matplotlib, Agg backend) for an evaluation."""
from __future__ import annotations

import html
import json
from pathlib import Path

import numpy as np

from holodata.metrics import HUMAN_CLUSTER_M, HUMAN_MIN_POINTS

COLORS = {"gt": "0.25", "model": "tab:blue", "baseline": "tab:orange", "model_no_refine": "tab:cyan",
          "model_analytic": "tab:brown", "oracle_stage1": "tab:olive"}
BEV_ORDER = ("gt", "model", "model_no_refine", "model_analytic", "baseline", "oracle_stage1")


def _plt():
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def fig_range_images(path: Path, ex: dict, max_range: float) -> None:
    plt = _plt()
    cols = ("gt", "model", "baseline")
    fig, axes = plt.subplots(3, 3, figsize=(13, 6.5), squeeze=False)
    for b in range(3):
        for c, name in enumerate(cols):
            ax = axes[b, c]
            img = np.ma.masked_invalid(ex[name][b])
            im = ax.imshow(img, vmin=0, vmax=max_range, cmap="viridis", aspect="auto", interpolation="nearest")
            ax.set_title(f"bounce {b + 1}: {'ground truth' if name == 'gt' else name}", fontsize=9)
            ax.set_xticks([])
            ax.set_yticks([])
    fig.colorbar(im, ax=axes, shrink=0.8, label="range R_b (m)")
    fig.suptitle(f"scene {ex['scene']}, frame {ex['frame']} (white = no return)")
    fig.savefig(path, dpi=90)
    plt.close(fig)


def fig_error_cdf(path: Path, errs: dict) -> None:
    plt = _plt()
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6), sharey=True)
    for b in range(3):
        ax = axes[b]
        for m, e in errs.items():
            e = np.sort(np.asarray(e[b])) * 100
            if e.size:
                ax.plot(e, np.arange(1, e.size + 1) / e.size, label=m, color=COLORS.get(m))
        ax.set_xscale("symlog", linthresh=1.0)
        ax.set_xlabel("absolute range error (cm)")
        ax.set_title(f"bounce {b + 1}")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("fraction of GT pixels")
    axes[0].legend()
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def fig_bev(path: Path, ex: dict) -> None:
    plt = _plt()
    names = [n for n in BEV_ORDER if n in ex["clouds"]]
    fig, axes = plt.subplots(1, len(names), figsize=(4.4 * len(names), 4.6), sharex=True, sharey=True, squeeze=False)
    axes = axes[0]
    for ax, name in zip(axes, names):
        cl = ex["clouds"][name]
        for part, col in (("los", "tab:green"), ("nlos", "tab:purple")):
            p = cl[part]
            if len(p):
                ax.scatter(p[:, 0], p[:, 1], s=1, c=col, label=f"{part.upper()} ({len(p)})", rasterized=True)
        ax.plot([0], [0], "k^", ms=6)
        ax.set_title("ground truth" if name == "gt" else name)
        ax.set_aspect("equal", adjustable="box")
        ax.set_xlabel("x (m, radar frame)")
        ax.legend(loc="upper right", fontsize=7, markerscale=6)
    axes[0].set_ylabel("y (m)")
    fig.suptitle(f"bird's-eye view, scene {ex['scene']} frame {ex['frame']}")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def fig_prf(path: Path, doc: dict) -> None:
    plt = _plt()
    fig, axes = plt.subplots(1, 2, figsize=(11, 3.8), sharey=True)
    for ax, part in zip(axes, ("los", "nlos")):
        for m, res in doc["methods"].items():
            c = res["prf_curve"][part]
            t = np.array(c["tau"]) * 100
            for key, ls in (("precision", ":"), ("recall", "--"), ("f_score", "-")):
                v = np.array([np.nan if x is None else x for x in c[key]], float)
                ax.plot(t, v, ls, color=COLORS.get(m), label=f"{m} {key}")
        ax.axvline(doc["settings"]["tau_m"] * 100, color="0.6", lw=0.8)
        ax.set_xlabel("threshold τ (cm)")
        ax.set_title(f"{part.upper()} point cloud")
        ax.set_ylim(0, 1.02)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("precision / recall / F")
    axes[1].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def fig_training(path: Path, log: Path) -> bool:
    rows = []
    for line in log.read_text().splitlines():
        try:
            rows.append(json.loads(line))
        except ValueError:
            pass
    if not rows:
        return False
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6, 3.4))
    ep = [r["epoch"] for r in rows]
    for key in ("loss", "l1", "grad", "valid", "human"):
        if key in rows[0]:
            ax.plot(ep, [r.get(key) for r in rows], label=key)
    ax.set_yscale("log")
    ax.set_xlabel("epoch")
    ax.set_ylabel("training loss")
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return True


def _f(v, nd=2, scale=1.0):
    return "–" if v is None else f"{v * scale:.{nd}f}"


def _tables(doc: dict) -> str:
    M = doc["methods"]
    h = ["<h2>Multi-return range images (stage 1)</h2><table><tr><th rowspan=2>method</th>"]
    h += [f"<th colspan=4>bounce {b}</th>" for b in (1, 2, 3)] + ["</tr><tr>"]
    h += ["<th>mean cm</th><th>median cm</th><th>90th cm</th><th>PSNR dB</th>"] * 3 + ["</tr>"]
    for m, r in M.items():
        h.append(f"<tr><td>{m}</td>")
        for b in (1, 2, 3):
            x = r["range"][f"bounce_{b}"]
            h.append("".join(f"<td>{_f(x[k])}</td>" for k in ("mean_cm", "median_cm", "p90_cm", "psnr_db")))
        h.append("</tr>")
    h.append("</table>")
    h.append("<h2>Scene reconstruction (un-mirrored point clouds)</h2><table><tr><th rowspan=2>method</th>"
             "<th colspan=3>LOS</th><th colspan=3>NLOS</th></tr><tr>"
             + "<th>CD cm</th><th>MHD cm</th><th>F-score %</th>" * 2 + "</tr>")
    for m, r in M.items():
        h.append(f"<tr><td>{m}</td>")
        for p in ("los", "nlos"):
            x = r["points"][p]
            h.append(f"<td>{_f(x['cd'], 1, 100)}</td><td>{_f(x['mhd'], 1, 100)}</td><td>{_f(x['f_score'], 1, 100)}</td>")
        h.append("</tr>")
    h.append("</table>")
    h.append("<h2>Human detection (50 cm matching)</h2><table><tr><th>method</th><th>precision %</th><th>recall %</th>"
             "<th>F-score %</th><th>loc. mean cm</th><th>loc. median cm</th><th>pred / GT</th></tr>")
    for m, r in M.items():
        x = r["human"]
        h.append(f"<tr><td>{m}</td><td>{_f(x['precision'], 1, 100)}</td><td>{_f(x['recall'], 1, 100)}</td>"
                 f"<td>{_f(x['f_score'], 1, 100)}</td><td>{_f(x['loc_mean_cm'], 1)}</td>"
                 f"<td>{_f(x['loc_median_cm'], 1)}</td><td>{x['n_pred']} / {x['n_gt']}</td></tr>")
    h.append("</table>")
    h.append("<h2>NLOS breakdown</h2><table><tr><th>group</th><th>band</th><th>scenes</th><th>frames</th>"
             + "".join(f"<th>{m} CD cm</th><th>{m} MHD cm</th><th>{m} F %</th>" for m in M) + "</tr>")
    first = next(iter(M))
    for group, bands in M[first]["breakdown"].items():
        for band, cell in bands.items():
            h.append(f"<tr><td>{group}</td><td>{html.escape(band)}</td><td>{cell['n_scenes']}</td><td>{cell['n_frames']}</td>")
            for m in M:
                c = M[m]["breakdown"][group].get(band, {})
                h.append(f"<td>{_f(c.get('cd'), 1, 100)}</td><td>{_f(c.get('mhd'), 1, 100)}</td>"
                         f"<td>{_f(c.get('f_score'), 1, 100)}</td>")
            h.append("</tr>")
    h.append("</table>")
    return "\n".join(h)


def write_report(out: Path, doc: dict, example: dict | None, errs: dict, train_log: Path | None = None) -> list[str]:
    """Write the PNG figures and report.html into ``out``; returns the figure file names."""
    figs: list[tuple[str, str]] = []
    mr = doc["settings"]["max_range_m"]
    if example is not None:
        fig_range_images(out / "range_images.png", example, mr)
        figs.append(("range_images.png", "Predicted vs true range images per bounce (example frame)"))
    fig_error_cdf(out / "error_cdf.png", errs)
    figs.append(("error_cdf.png", "Cumulative distribution of absolute range errors per bounce"))
    if example is not None:
        fig_bev(out / "bev_clouds.png", example)
        figs.append(("bev_clouds.png", "Bird's-eye view of LOS (green) and NLOS (purple) point clouds"))
    fig_prf(out / "prf_curves.png", doc)
    figs.append(("prf_curves.png", "Precision / recall / F-score over the distance threshold τ"))
    if train_log is not None and train_log.exists() and fig_training(out / "training_loss.png", train_log):
        figs.append(("training_loss.png", "Training losses per epoch"))
    s = doc["settings"]
    body = [
        "<!DOCTYPE html><html lang=en><head><meta charset=utf-8><title>holodata evaluation</title>",
        "<style>body{font-family:sans-serif;max-width:1200px;margin:2em auto;color:#222}"
        "table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #bbb;padding:3px 8px;text-align:right}"
        "th{background:#eee}figure{margin:1.5em 0}img{max-width:100%}figcaption{color:#555}</style></head><body>",
        "<h1>holodata evaluation</h1>",
        f"<p>dataset <code>{html.escape(doc['dataset'])}</code>, split <b>{html.escape(doc['split'])}</b> "
        f"({doc['n_frames']} frames, scenes {html.escape(', '.join(doc['scenes']))}); checkpoint "
        f"<code>{html.escape(doc['checkpoint'])}</code> ({s['train_epochs']} epochs). Baseline: {html.escape(s['baseline'])}. "
        f"CD = sum of the two directed mean distances, MHD = their max, F-score at τ = {s['tau_m'] * 100:.0f} cm. "
        f"Stage two: {html.escape(str(s.get('stage2', 'analytic (normals from the range images, paper eq. 2-5)')))}"
        + (" (rows: model = refined, model_no_refine = the learned ray tracer's points, model_analytic = eq. 2–5 "
           "on the model's ranges, oracle_stage1 = GT range images through the learned stage two)"
           if "oracle_stage1" in doc["methods"] else "")
        + (f". GT NLOS points per frame: "
           f"{s['gt_nlos_points_per_frame']:.0f}" if s.get("gt_nlos_points_per_frame") is not None else "")
        + ".</p>",
        _tables(doc),
    ]
    for name, cap in figs:
        body.append(f"<figure><img src=\"{name}\" "
                    f"alt=\"{html.escape(cap)}\"><figcaption>{html.escape(cap)}</figcaption></figure>")
    body.append("<p>Machine-readable numbers: <a href=\"metrics.json\">metrics.json</a>.</p>")
    # marks the page once every figure decoded: <body data-images-ok="yes|no"> (checked headless)
    body.append("<script>window.addEventListener('load',function(){var bad=0;for(var i=0;i<document.images.length;i++)"
                "{var im=document.images[i];if(!im.complete||im.naturalWidth===0)bad++;}"
                "document.body.setAttribute('data-images-ok',bad===0?'yes':'no');});</script></body></html>")
    (out / "report.html").write_text("\n".join(body) + "\n")
    return [n for n, _ in figs]


CHROMIUM_NAMES = ("chromium-headless-shell", "chromium", "chromium-browser", "google-chrome", "chrome")


def find_chromium() -> str | None:
    import shutil

    for name in CHROMIUM_NAMES:
        path = shutil.which(name)
        if path:
            return path
    return None


def _chromium_cmd(html_path: Path, *extra: str) -> list[str]:
    from holodata.errors import HolodataError

    exe = find_chromium()
    if exe is None:
        raise HolodataError("headless Chromium not found (install Debian's `chromium-headless-shell` package; "
                            "scripts/setup.sh does) — needed for --screenshot")
    return [exe, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars", "--allow-file-access-from-files",
            "--virtual-time-budget=5000", *extra, Path(html_path).resolve().as_uri()]


def screenshot(html_path: Path, png_path: Path, width: int = 1280, height: int = 3000) -> Path:
    """Save a PNG of the rendered report with headless Chromium."""
    import subprocess

    cmd = _chromium_cmd(html_path, f"--screenshot={Path(png_path).resolve()}", f"--window-size={width},{height}")
    subprocess.run(cmd, check=True, capture_output=True, timeout=120)
    return Path(png_path)


def check_in_browser(html_path: Path) -> dict:
    """Load the report in headless Chromium: {"images_ok": bool, "console_errors": [lines]}."""
    import subprocess

    cmd = _chromium_cmd(html_path, "--dump-dom", "--enable-logging=stderr", "--v=0")
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    errs = [ln for ln in r.stderr.splitlines()
            if "CONSOLE" in ln and ("Uncaught" in ln or "Error" in ln or "Failed to load" in ln)]
    return {"images_ok": 'data-images-ok="yes"' in r.stdout, "console_errors": errs}


def format_tables(doc: dict) -> str:
    """The metrics document as two plain-text tables (range errors per bounce; point clouds)."""
    def f(v, scale=1.0, nd=1):
        return "   –  " if v is None else f"{v * scale:6.{nd}f}"

    nl = doc["settings"].get("gt_nlos_points_per_frame")
    lines = [f"{doc['split']}: {doc['n_frames']} frames, scenes {', '.join(doc['scenes'])}"
             + ("" if nl is None else f"; GT NLOS points per frame {nl:.0f}"),
             "range error (cm)         b1 mean/med/p90          b2 mean/med/p90          b3 mean/med/p90"]
    for m, r in doc["methods"].items():
        keys = ("mean_cm", "median_cm", "p90_cm")
        cells = "   ".join(" ".join(f(r["range"][f"bounce_{b}"][k]) for k in keys) for b in (1, 2, 3))
        lines.append(f"  {m:<15} {cells}")
    lines.append("point clouds             LOS CD cm / MHD cm / F %     NLOS CD cm / MHD cm / F %     human F % (all / hidden)")
    for m, r in doc["methods"].items():
        p = r["points"]
        lines.append(f"  {m:<15} " + " ".join(f(p["los"][k], 100) for k in ("cd", "mhd", "f_score")) + "   "
                     + " ".join(f(p["nlos"][k], 100) for k in ("cd", "mhd", "f_score")) + "   " + f(r["human"]["f_score"], 100)
                     + " / " + f(r.get("human_hidden", {}).get("f_score"), 100))
    hum = next(iter(doc["methods"].values()), {}).get("human") or {}
    if hum.get("n_gt") == 0:
        lines.append("  human F –: no frame of the split holds a person in the ground truth (a person counts from "
                     f"{HUMAN_MIN_POINTS} human-labelled GT returns within {HUMAN_CLUSTER_M * 100:.0f} cm of each other)")
    return "\n".join(lines)
