"""Regenerate docs/img/main-screen.png: fviz's main screen (the overview tab of `fviz inspect pair`) in the real
web viewer, made from SYNTHETIC data (no dataset needed).

    python docs/make_screenshot.py            # needs Debian's chromium (bash .ci/install-browser) and the test extra

Steps: `fviz inspect pair --synthetic --seed 0 --pair temporal` writes a recording; `fviz open REC --web` serves it;
headless chromium (tests/browser.py, the harness of the browser tests) loads the printed URL; the screenshot is
taken once the viewer has settled, downscaled and written as PNG (< 500 KB).
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))

import cv2  # noqa: E402
from browser import Chromium, WebServer, decode_png, require_chromium, run_fviz  # noqa: E402

OUT = ROOT / "docs" / "img" / "main-screen.png"
WIDTHS = (1200, 1100, 1000, 900, 800)  # the viewport is 1600 x 1000: the widest of these that fits MAX_BYTES
MAX_BYTES = 480_000


def rendered(rgb) -> bool:
    """The viewer's panels are drawn (its loading screen has few colours)."""
    q = (rgb // 16).astype("int32")
    return len(set((q[..., 0] * 65536 + q[..., 1] * 256 + q[..., 2]).ravel().tolist())) > 150 and float(rgb.std()) > 25


def main() -> int:
    require_chromium()
    with tempfile.TemporaryDirectory(prefix="fviz-shot-") as tmp:
        rec = Path(tmp) / "synthetic.rrd"
        r = run_fviz("inspect", "pair", "--synthetic", "--seed", "0", "--pair", "temporal", "--out", rec)
        if r.returncode != 0:
            print(r.stderr, file=sys.stderr)
            return 1
        with WebServer(rec) as server, Chromium(server.url) as browser:
            png, rgb, seconds, n = browser.wait_stable(rendered, timeout=600, shot_timeout=300)
        if not rendered(rgb):
            print("the viewer did not render", file=sys.stderr)
            return 1
    bgr = cv2.cvtColor(decode_png(png), cv2.COLOR_RGB2BGR)
    h, w = bgr.shape[:2]
    for width in WIDTHS:
        small = cv2.resize(bgr, (width, round(h * width / w)), interpolation=cv2.INTER_AREA)
        ok, data = cv2.imencode(".png", small, [cv2.IMWRITE_PNG_COMPRESSION, 9])
        if ok and len(data) <= MAX_BYTES:
            break
    OUT.parent.mkdir(parents=True, exist_ok=True)
    OUT.write_bytes(data.tobytes())
    print(f"{OUT.relative_to(ROOT)}: {small.shape[1]}x{small.shape[0]}, {OUT.stat().st_size / 1e3:.0f} KB "
          f"(settled after {seconds:.0f} s, {n} screenshots)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
