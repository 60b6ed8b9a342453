"""Screenshot of `holodata view --web` in headless Chromium, and a check that the viewer drew a scene.

Starts `holodata view DATASET --scene ID --web --port P`, opens Rerun's web viewer in Debian's
`chromium-headless-shell` (software WebGL: SwiftShader) through the DevTools protocol (aiohttp's
websocket client), waits until the viewer has drawn, saves the PNG and fails when the scene is not in it (fewer than
5 % strongly coloured pixels: the viewer's chrome and its welcome page are grey).

    .venv/bin/python scripts/viewer_screenshot.py holodata-demo/dataset.zarr --scene L_16 --out docs/viewer.png
"""
from __future__ import annotations

import argparse
import asyncio
import base64
import json
import shutil
import subprocess
import sys
import tempfile
import time
import urllib.parse
import urllib.request
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
FLAGS = ["--headless", "--no-sandbox", "--use-gl=angle", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
         "--no-first-run", "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--window-size=1400,900"]


def _wait_http(url: str, seconds: float) -> None:
    t0 = time.time()
    while time.time() - t0 < seconds:
        try:
            urllib.request.urlopen(url, timeout=2).read(1)
            return
        except OSError:
            time.sleep(0.5)
    raise SystemExit(f"{url}: nothing answered within {seconds:.0f} s")


async def _capture(devtools: int, page_url: str, wait_s: float) -> bytes:
    import aiohttp

    tabs = json.loads(urllib.request.urlopen(f"http://127.0.0.1:{devtools}/json", timeout=5).read())
    ws_url = next(t["webSocketDebuggerUrl"] for t in tabs if t.get("type") == "page")
    async with aiohttp.ClientSession() as s, s.ws_connect(ws_url, max_msg_size=0) as ws:
        n = 0

        async def call(method, **params):
            nonlocal n
            n += 1
            await ws.send_str(json.dumps({"id": n, "method": method, "params": params}))
            while True:
                msg = json.loads((await ws.receive()).data)
                if msg.get("id") == n:
                    return msg.get("result", {})

        await call("Page.enable")
        await call("Page.navigate", url=page_url)
        await asyncio.sleep(wait_s)
        shot = await call("Page.captureScreenshot", format="png")
        return base64.b64decode(shot["data"])


def colourful_fraction(png: bytes) -> float:
    """Share of strongly coloured pixels (max - min channel > 60): the viewer's own chrome and its
    welcome page are grey and white, the scene's panels (colour-mapped depth and label images,
    points coloured by class) are not."""
    import cv2

    img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR).astype(np.int32)
    return float(np.mean(img.max(axis=2) - img.min(axis=2) > 60))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("dataset")
    ap.add_argument("--scene", default=None)
    ap.add_argument("--out", default="viewer.png")
    ap.add_argument("--port", type=int, default=9090)
    ap.add_argument("--wait", type=float, default=25.0, help="seconds to let the viewer load and draw")
    a = ap.parse_args(argv)
    chromium = shutil.which("chromium-headless-shell") or shutil.which("chromium")
    if chromium is None:
        raise SystemExit("no headless Chromium (Debian: apt-get install chromium-headless-shell)")
    holodata = [sys.executable, "-m", "holodata.cli.main", "view", a.dataset, "--web", "--port", str(a.port)]
    if a.scene:
        holodata += ["--scene", a.scene]
    viewer = subprocess.Popen(holodata, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    profile = tempfile.mkdtemp(prefix="holodata-chromium-")
    browser = None
    try:
        _wait_http(f"http://127.0.0.1:{a.port}/", 60)
        browser = subprocess.Popen([chromium, *FLAGS, f"--user-data-dir={profile}", "--remote-debugging-port=9333",
                                    "about:blank"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        _wait_http("http://127.0.0.1:9333/json/version", 30)
        data = urllib.parse.quote(f"rerun+http://localhost:{a.port + 1}/proxy", safe="")
        png = asyncio.run(_capture(9333, f"http://localhost:{a.port}/?url={data}", a.wait))
    finally:
        for p in (browser, viewer):
            if p is not None:
                p.terminate()
                try:
                    p.wait(10)
                except subprocess.TimeoutExpired:
                    p.kill()
        shutil.rmtree(profile, ignore_errors=True)
    Path(a.out).write_bytes(png)
    frac = colourful_fraction(png)
    print(f"{a.out}: {len(png)} bytes, {100 * frac:.1f} % of the pixels coloured (the scene's panels; >= 5 % passes)")
    return 0 if frac >= 0.05 else 1


if __name__ == "__main__":
    sys.exit(main())
