"""The commissioning report printed to PDF by a headless Chromium (``ambdaq report --pdf``)."""

from __future__ import annotations

import shutil
import subprocess
import tempfile
from pathlib import Path

from ..errors import BadInputError

BROWSERS = ("chromium", "chromium-browser", "google-chrome")
# what Debian's chromium needs to run headless here without reaching for the network
HEADLESS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
            "--disable-background-networking", "--disable-component-update", "--disable-sync")


def browser() -> str:
    """A headless-capable Chromium on the PATH; one line naming the package otherwise."""
    for name in BROWSERS:
        found = shutil.which(name)
        if found:
            return found
    raise BadInputError("--pdf needs a Chromium (Debian: apt-get install chromium)")


def print_pdf(page: Path, pdf: Path) -> None:
    """``page`` printed to ``pdf`` by headless Chromium."""
    with tempfile.TemporaryDirectory(prefix="ambdaq-chromium-") as profile:
        r = subprocess.run([browser(), *HEADLESS, f"--user-data-dir={profile}", "--no-pdf-header-footer",
                            f"--print-to-pdf={pdf}", page.resolve().as_uri()], capture_output=True, text=True, timeout=120)
    if r.returncode != 0 or not pdf.exists():
        raise BadInputError(f"chromium could not print {page}: {(r.stderr.strip().splitlines() or ['no output'])[-1]}")
