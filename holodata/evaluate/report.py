"""report.html + PNG figures (:mod:`holodata.evaluate.figures`) for an evaluation.

The page, top to bottom: the hidden side first (one large bird's-eye picture per held-out frame:
GT and predicted LOS/NLOS points, the person's true and predicted centres), then the tables
(scene reconstruction, NLOS by corner shape / width / attenuation in the paper's Table-3 layout,
human detection, range images per bounce), then the other figures. Laid out for a 1280 px window:
a 1200 px column, tables that fit it, figures about 1170 px wide (checked by
tests/evaluate/test_report_browser.py through :func:`check_layout`)."""
from __future__ import annotations

import html
import json
from pathlib import Path

from holodata.metrics import HUMAN_CLUSTER_M, HUMAN_MIN_POINTS

from .figures import BEV_ORDER, COLORS, fig_bev, fig_error_cdf, fig_hidden_side, fig_prf, fig_range_images, fig_training  # noqa: F401

# the paper's Table 3 rows, in its order: (group, band, label); bands the split lacks show "–"
TABLE3_ROWS = (
    ("shape", "T", "T-shaped"), ("shape", "cross", "Cross-shaped"), ("shape", "L", "L-shaped"),
    ("width", "narrow", "Narrow (< 1.5 m)"), ("width", "medium", "Medium (1.5–3 m)"), ("width", "wide", "Wide (> 3 m)"),
    ("attenuation", "high", "High (> 20 dB)"), ("attenuation", "medium", "Medium (10–20 dB)"),
    ("attenuation", "low", "Low (< 10 dB)"),
)
GROUP_LABELS = {"shape": "Shape", "width": "Size", "attenuation": "Signal atten."}

CSS = ("*{box-sizing:border-box}body{font-family:sans-serif;max-width:1200px;margin:1.5em auto;padding:0 0.5em;"
       "color:#222;line-height:1.4}"
       ".tw{max-width:100%;overflow-x:auto}"
       "table{border-collapse:collapse;margin:0.6em 0 1.4em;font-size:13px}"
       "td,th{border:1px solid #bbb;padding:2px 6px;text-align:right;white-space:nowrap}"
       "th{background:#eee}th[colspan]{text-align:center}td.l,th.l{text-align:left}tr.g td{border-top:2px solid #888}"
       "figure{margin:1.2em 0 2em}img{max-width:100%;height:auto;display:block}figcaption{color:#555}"
       "p.note{color:#444;font-size:14px}caption{caption-side:bottom;text-align:left;color:#555;font-size:13px;"
       "padding-top:4px}")


def _f(v, nd=2, scale=1.0):
    return "–" if v is None or v != v else f"{v * scale:.{nd}f}"   # None / NaN: undefined (no person)


def _table(rows: list[str]) -> str:
    return "<div class=tw><table>" + "".join(rows) + "</table></div>"


def _table3(M: dict) -> str:
    """NLOS reconstruction by corner shape, width and attenuation: the paper's Table 3 (rows = the
    bands, columns = CD / MHD / F-score), one column group per method."""
    first = next(iter(M))
    seen = {(g, b) for g, bands in M[first]["breakdown"].items() for b in bands}
    rows = list(TABLE3_ROWS) + [(g, b, b) for g, b in sorted(seen) if (g, b) not in {(r[0], r[1]) for r in TABLE3_ROWS}]
    rows.sort(key=lambda r: list(GROUP_LABELS).index(r[0]) if r[0] in GROUP_LABELS else 99)
    h = ["<caption>NLOS point clouds per band of the held-out scenes: CD and MHD in cm (lower is better), "
         "F-score in % (higher is better); bands the split lacks show –.</caption>"
         "<tr><th class=l rowspan=2>setting</th><th class=l rowspan=2>variation</th><th rowspan=2>scenes /<br>frames</th>"
         + "".join(f"<th colspan=3>{html.escape(m)}</th>" for m in M) + "</tr><tr>"
         + "<th>CD</th><th>MHD</th><th>F</th>" * len(M) + "</tr>"]
    last = None
    for group, band, label in rows:
        cell = M[first]["breakdown"].get(group, {}).get(band)
        new = group != last
        span = sum(1 for r in rows if r[0] == group)
        h.append(f"<tr{' class=g' if new and last is not None else ''}>"
                 + (f"<td class=l rowspan={span}>{html.escape(GROUP_LABELS.get(group, group))}</td>" if new else "")
                 + f"<td class=l>{html.escape(label)}</td>"
                 f"<td>{cell['n_scenes'] if cell else 0} / {cell['n_frames'] if cell else 0}</td>")
        for m in M:
            c = M[m]["breakdown"].get(group, {}).get(band) or {}
            h.append(f"<td>{_f(c.get('cd'), 1, 100)}</td><td>{_f(c.get('mhd'), 1, 100)}</td>"
                     f"<td>{_f(c.get('f_score'), 1, 100)}</td>")
        h.append("</tr>")
        last = group
    return _table(h)


def _tables(doc: dict) -> str:
    M = doc["methods"]
    out = ["<h2>Scene reconstruction (un-mirrored point clouds)</h2>"]
    h = ["<tr><th class=l rowspan=2>method</th><th colspan=3>LOS</th><th colspan=3>NLOS (hidden side)</th></tr><tr>"
         + "<th>CD cm ↓</th><th>MHD cm ↓</th><th>F % ↑</th>" * 2 + "</tr>"]
    for m, r in M.items():
        h.append(f"<tr><td class=l>{html.escape(m)}</td>")
        for p in ("los", "nlos"):
            x = r["points"][p]
            h.append(f"<td>{_f(x['cd'], 1, 100)}</td><td>{_f(x['mhd'], 1, 100)}</td><td>{_f(x['f_score'], 1, 100)}</td>")
        h.append("</tr>")
    out.append(_table(h))
    out.append("<h2>NLOS reconstruction by corner shape, size and signal attenuation (paper Table 3)</h2>")
    out.append(_table3(M))
    out.append("<h2>Human detection (50 cm matching; paper §5.2): every frame, and the frames whose person is "
               "hidden</h2>")
    cols = "<th>precision / recall / F %</th><th>loc. mean / median cm</th><th>pred / GT</th>"
    h = [f"<tr><th class=l rowspan=2>method</th><th colspan=3>all frames</th><th colspan=3>hidden person</th></tr>"
         f"<tr>{cols}{cols}</tr>"]
    for m, r in M.items():
        h.append(f"<tr><td class=l>{html.escape(m)}</td>" + "".join(
            f"<td>{_f(x.get('precision'), 1, 100)} / {_f(x.get('recall'), 1, 100)} / {_f(x.get('f_score'), 1, 100)}</td>"
            f"<td>{_f(x.get('loc_mean_cm'), 1)} / {_f(x.get('loc_median_cm'), 1)}</td>"
            f"<td>{x.get('n_pred', '–')} / {x.get('n_gt', '–')}</td>"
            for x in (r["human"], r.get("human_hidden") or {})) + "</tr>")
    out.append(_table(h))
    out.append("<h2>Multi-return range images (stage 1)</h2>")
    h = ["<tr><th class=l rowspan=2>method</th>"] + [f"<th colspan=4>bounce {b}</th>" for b in (1, 2, 3)] + ["</tr><tr>"]
    h += ["<th>mean cm</th><th>median cm</th><th>90th cm</th><th>PSNR dB</th>"] * 3 + ["</tr>"]
    for m, r in M.items():
        h.append(f"<tr><td class=l>{html.escape(m)}</td>")
        for b in (1, 2, 3):
            x = r["range"][f"bounce_{b}"]
            h.append("".join(f"<td>{_f(x[k])}</td>" for k in ("mean_cm", "median_cm", "p90_cm", "psnr_db")))
        h.append("</tr>")
    out.append(_table(h))
    return "\n".join(out)


def _figure(name: str, cap: str) -> str:
    return (f"<figure><img src=\"{name}\" alt=\"{html.escape(cap)}\"><figcaption>{html.escape(cap)}</figcaption></figure>")


def write_report(out: Path, doc: dict, example: dict | None, errs: dict, train_log: Path | None = None,
                 frames: list[dict] | None = None) -> list[str]:
    """Write the PNG figures and report.html into ``out``; returns the figure file names.
    ``frames``: held-out frames for the hidden-side pictures (pipeline ``_report_frame``), first on the page."""
    out = Path(out)
    s = doc["settings"]
    oracle = doc.get("checkpoint") == "oracle"
    method = "model"
    hidden: list[tuple[str, str]] = []
    for n, fr in enumerate(frames or []):
        name = f"hidden_side_{n + 1}.png"
        fig_hidden_side(out / name, fr, method)
        hidden.append((name, f"Held-out frame {n + 1} of {len(frames)}: scene {fr['scene']}, frame {fr['frame']}, "
                             f"from above. Grey / purple: ground-truth LOS / NLOS points; green / red ×: the {method}'s "
                             f"LOS / NLOS points; star: the person's true centre; blue X: the {method}'s centre."))
    figs: list[tuple[str, str]] = []
    if example is not None:
        fig_bev(out / "bev_clouds.png", example)
        figs.append(("bev_clouds.png", "Every row's LOS (green) and NLOS (purple) points of one frame, from above"))
    fig_prf(out / "prf_curves.png", doc)
    figs.append(("prf_curves.png", "Precision / recall / F-score over the distance threshold τ (grey line: the τ of the tables)"))
    fig_error_cdf(out / "error_cdf.png", errs)
    figs.append(("error_cdf.png", "Cumulative distribution of absolute range errors per bounce"))
    if example is not None:
        fig_range_images(out / "range_images.png", example, s["max_range_m"])
        figs.append(("range_images.png", "Predicted vs true range images per bounce (example frame)"))
    if train_log is not None and train_log.exists() and fig_training(out / "training_loss.png", train_log):
        figs.append(("training_loss.png", "Training losses per epoch"))
    nl = s.get("gt_nlos_points_per_frame")
    body = [
        "<!DOCTYPE html><html lang=en><head><meta charset=utf-8>"
        "<meta name=viewport content=\"width=device-width, initial-scale=1\"><title>holodata evaluation</title>",
        f"<style>{CSS}</style></head><body>",
        "<h1>holodata evaluation</h1>",
        f"<p>Split <b>{html.escape(doc['split'])}</b> of <code>{html.escape(doc['dataset'])}</code>: {doc['n_frames']} "
        f"held-out frames, scenes {html.escape(', '.join(doc['scenes']))}; checkpoint "
        f"<code>{html.escape(doc['checkpoint'])}</code>"
        + (" (the ground truth scored as the prediction: a check of the metrics)" if oracle else
           f" ({s['train_epochs']} epochs)")
        + (f"; {nl:.0f} ground-truth NLOS points per frame" if nl is not None else "") + ".</p>",
    ]
    if hidden:
        body.append("<h2>The hidden side, frame by frame</h2>"
                    f"<p class=note>{len(hidden)} held-out frames, spread over the split, seen from above in the radar's "
                    f"frame (the radar is the black triangle). What matters is the purple ground truth behind the corner "
                    f"(NLOS) and whether the {method}'s red × points land on it; the dashed circle around the "
                    f"person's true centre is the {s.get('human_match_m', 0.5) * 100:.0f} cm within which a predicted "
                    f"centre counts as a detection.</p>")
        body += [_figure(n, c) for n, c in hidden]
    body.append(
        f"<p class=note>CD = sum of the two directed mean distances, MHD = their max, F-score at τ = {s['tau_m'] * 100:.0f} cm. "
        f"Baseline: {html.escape(s['baseline'])}. "
        f"Stage two: {html.escape(str(s.get('stage2', 'analytic (normals from the range images, paper eq. 2-5)')))}"
        + (" (rows: model = refined, model_no_refine = the learned ray tracer's points, model_analytic = eq. 2–5 "
           "on the model's ranges, oracle_stage1 = GT range images through the learned stage two)"
           if "oracle_stage1" in doc["methods"] else "") + ".</p>")
    body.append(_tables(doc))
    body.append("<h2>Figures</h2>")
    body += [_figure(n, c) for n, c in figs]
    body.append("<p>Machine-readable numbers: <a href=\"metrics.json\">metrics.json</a>.</p>")
    # marks the page once every figure decoded: <body data-images-ok="yes|no"> (checked headless)
    body.append("<script>window.addEventListener('load',function(){var bad=0;for(var i=0;i<document.images.length;i++)"
                "{var im=document.images[i];if(!im.complete||im.naturalWidth===0)bad++;}"
                "document.body.setAttribute('data-images-ok',bad===0?'yes':'no');});</script></body></html>")
    (out / "report.html").write_text("\n".join(body) + "\n")
    return [n for n, _ in hidden + figs]


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
        return "   –  " if v is None or v != v else f"{v * scale:6.{nd}f}"

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
    lines.append("human detection (50 cm)  all frames: P / R / F %, loc. mean / median cm     "
                 "hidden person: P / R / F %, loc. mean / median cm")
    for m, r in doc["methods"].items():
        lines.append(f"  {m:<15} " + "      ".join(
            " ".join(f(x.get(k), 100) for k in ("precision", "recall", "f_score")) + "  "
            + " ".join(f(x.get(k)) for k in ("loc_mean_cm", "loc_median_cm"))
            for x in (r["human"], r.get("human_hidden") or {})))
    hum = next(iter(doc["methods"].values()), {}).get("human") or {}
    if hum.get("n_gt") == 0:
        lines.append("  human F –: no frame of the split holds a person in the ground truth (a person counts from "
                     f"{HUMAN_MIN_POINTS} human-labelled GT returns within {HUMAN_CLUSTER_M * 100:.0f} cm of each other)")
    return "\n".join(lines)


# measures the rendered page: every <img> (src, natural and on-page width), every table's right edge,
# the document's scroll width against the viewport; written as JSON into <pre id="holodata-layout">
_LAYOUT_JS = """<script>window.addEventListener('load',function(){
var vw=document.documentElement.clientWidth,imgs=[],tables=[];
for(var i=0;i<document.images.length;i++){var im=document.images[i];
imgs.push({src:im.getAttribute('src'),complete:im.complete,natural_width:im.naturalWidth,
client_width:im.getBoundingClientRect().width});}
var ts=document.getElementsByTagName('table');
for(var j=0;j<ts.length;j++){var r=ts[j].getBoundingClientRect();
tables.push({index:j,left:r.left,right:r.right,width:r.width});}
var p=document.createElement('pre');p.id='holodata-layout';p.hidden=true;
p.textContent=JSON.stringify({viewport_width:vw,inner_width:window.innerWidth,
scroll_width:document.documentElement.scrollWidth,images:imgs,tables:tables});
document.body.appendChild(p);});</script>"""


def check_layout(html_path: Path, width: int = 1280, height: int = 900) -> dict:
    """Render the report in headless Chromium at ``width`` × ``height`` px and measure it:
    {"viewport_width", "inner_width", "scroll_width", "images": [{src, complete, natural_width,
    client_width}], "tables": [{index, left, right, width}]} (sizes in CSS px). The page is measured
    through a copy beside it (so that its relative image paths resolve), removed afterwards."""
    import re
    import subprocess
    import uuid

    from holodata.errors import HolodataError

    html_path = Path(html_path)
    # a new name of its own beside the page ("x": never an existing file, nor through a symlink)
    probe = html_path.with_name(f".{html_path.stem}.layout-probe.{uuid.uuid4().hex}.html")
    text = html_path.read_text()
    text = text.replace("</body>", _LAYOUT_JS + "</body>") if "</body>" in text else text + _LAYOUT_JS
    with open(probe, "x") as fh:
        fh.write(text)
    try:
        cmd = _chromium_cmd(probe, "--dump-dom", f"--window-size={width},{height}")
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    finally:
        probe.unlink(missing_ok=True)
    m = re.search(r'<pre id="holodata-layout"[^>]*>(.*?)</pre>', r.stdout, re.S)
    if m is None:
        raise HolodataError(f"headless Chromium did not measure {html_path} (exit {r.returncode}): {r.stderr[-500:]}")
    return json.loads(html.unescape(m.group(1)))
