"""The README's pictures of a sweep report, taken in headless Chromium.

Usage: python benchmarks/screenshots.py REPORT.html --top PNG [--run TEXT IMAGE]

``--top`` writes the page's first screen (the best configuration per family and the
first threshold plots, 832 pixels wide); ``--run`` the section of the run whose heading
contains TEXT (its table, trajectory, error plot and frames), as PNG or JPEG by the
file's suffix. Debian's chromium, driven by Playwright, as tests/test_report.py opens
the same pages (`make readme-images` runs it on the demo's report).
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
from pathlib import Path

# depotbench first: numpy then runs the bench's code for the CPU (core/numerics.py)
import depotbench  # isort: skip  # noqa: F401
import cv2

BROWSERS = ("chromium", "chromium-browser")
WIDTH, TOP_HEIGHT = 1100, 1184
"""CSS pixels: the best-configuration table's ten columns need about 1000 of the width
(at 832 its last two scrolled out of view), and the top screen shows that table and the
first threshold plot."""


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("report", type=Path)
    parser.add_argument("--top", type=Path, required=True)
    parser.add_argument("--run", nargs=2, metavar=("TEXT", "IMAGE"))
    args = parser.parse_args()
    if not args.report.is_file():
        parser.error(f"{args.report}: no such report page")
    executable = next((shutil.which(b) for b in BROWSERS if shutil.which(b)), None)
    if executable is None:
        parser.error("no Chromium: `make browser` installs Debian's chromium package")
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p, tempfile.TemporaryDirectory() as tmp:
        browser = p.chromium.launch(executable_path=executable, args=["--no-sandbox"])
        page = browser.new_page(viewport={"width": WIDTH, "height": TOP_HEIGHT})
        page.goto(args.report.resolve().as_uri(), wait_until="load")
        _save(page.screenshot(), args.top, Path(tmp))
        if args.run:
            text, image = args.run
            section = page.locator("section", has=page.locator("h2", has_text=text)).first
            if section.count() == 0:
                parser.error(f"{args.report}: no run section whose heading contains {text!r}")
            _save(section.screenshot(), Path(image), Path(tmp))
        browser.close()
    print(f"wrote {args.top}" + (f" and {args.run[1]}" if args.run else ""))


def _save(png: bytes, path: Path, tmp: Path) -> None:
    """Write the screenshot as PNG, or as JPEG (quality 85) for a .jpg path."""
    if path.suffix.lower() == ".png":
        path.write_bytes(png)
        return
    shot = tmp / "shot.png"
    shot.write_bytes(png)
    if not cv2.imwrite(str(path), cv2.imread(str(shot)), [cv2.IMWRITE_JPEG_QUALITY, 85]):
        raise SystemExit(f"{path}: could not write the picture")


if __name__ == "__main__":
    main()
