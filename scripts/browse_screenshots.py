"""Screenshots of a running ``d5rl browse`` page in headless Chromium (the README's images).

    d5rl browse &                                  # with the datasets you want to show
    python scripts/browse_screenshots.py http://127.0.0.1:8765/#/task/a1-walk-v0/episode/0 docs/img/browse-episode.png

    d5rl browse docs/results/table1-state/cells docs/results/table1-pixels/cells docs/results/a1-o2o/cells &
    python scripts/browse_screenshots.py http://127.0.0.1:8765/#/runs docs/img/browse-runs.png \
        --element 'section.task-runs[data-task="a1-walk-v0"]'

Waits until the view's frames and plots are drawn (``--frame N`` scrubs to frame N first), then
writes a PNG of the window, or of one element of the page (``--element SELECTOR``), optimized with Pillow
(``--width``/``--height`` set the window).
"""

from __future__ import annotations

import argparse
import io
import shutil
import tempfile

from PIL import Image
from playwright.sync_api import sync_playwright

ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("url")
    p.add_argument("out")
    p.add_argument("--frame", type=int, help="scrub an episode view to this frame")
    p.add_argument("--element", help="CSS selector of the one element to capture (default: the window)")
    p.add_argument("--width", type=int, default=1280)
    p.add_argument("--height", type=int, default=900)
    p.add_argument("--colors", type=int, default=128, help="palette size of the PNG (smaller file)")
    args = p.parse_args()
    with tempfile.TemporaryDirectory() as profile, sync_playwright() as pw:
        ctx = pw.chromium.launch_persistent_context(
            profile,
            executable_path=shutil.which("chromium"),
            headless=True,
            args=ARGS,
            viewport={"width": args.width, "height": args.height},
        )
        page = ctx.new_page()
        page.set_default_timeout(120_000)
        page.goto(args.url)
        page.wait_for_function("document.body.dataset.ready !== undefined")
        if "/episode/" in args.url:
            page.wait_for_selector('.frame[data-loaded="1"]')
            if args.frame is not None:
                page.fill("#scrubber", str(args.frame))
                page.dispatch_event("#scrubber", "input")
        page.wait_for_timeout(1500)  # plots finish drawing
        png = page.locator(args.element).screenshot() if args.element else page.screenshot()
        ctx.close()
    Image.open(io.BytesIO(png)).convert("RGB").quantize(args.colors).save(args.out, optimize=True)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
