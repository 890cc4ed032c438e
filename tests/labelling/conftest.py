"""The labelling tests' browser (Debian's Chromium driven by Playwright, nothing downloaded) and server processes."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest

CHROMIUM = "/usr/bin/chromium"
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
         "--disable-component-update", "--disable-sync"]
URL = re.compile(r"(http://127\.0\.0\.1:\d+/\?token=[A-Za-z0-9_-]+)")


@pytest.fixture
def screenshots(tmp_path) -> Path:
    """Where the browser tests put their screenshots: ``ICPRL_LABEL_SCREENSHOTS`` (docs/figures) or ``tmp_path``."""
    return Path(os.environ.get("ICPRL_LABEL_SCREENSHOTS", str(tmp_path)))


@pytest.fixture(scope="module")
def browser():
    """Headless system Chromium; the test skips, saying why, where it or Playwright is missing."""
    if not Path(CHROMIUM).exists():
        pytest.skip(f"browser tests need Debian's chromium at {CHROMIUM} (apt-get install -y chromium; .ci/run does)")
    playwright = pytest.importorskip("playwright.sync_api", reason="browser tests need the playwright package")
    with playwright.sync_playwright() as p:
        chromium = p.chromium.launch(executable_path=CHROMIUM, args=FLAGS)
        yield chromium
        chromium.close()


class Server:
    """``icprl label`` in its own process (so that it can be SIGKILLed), and the address it printed."""

    def __init__(self, *args: str) -> None:
        env = {**os.environ, "OMP_NUM_THREADS": "1"}
        self.process = subprocess.Popen([sys.executable, "-m", "icprl_lightning.commands.label", *args, "--port", "0"],
                                        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
        for line in self.process.stdout:
            found = URL.search(line)
            if found:
                self.url = found.group(1)
                return
        raise AssertionError(f"icprl label printed no address: {self.process.stderr.read()}")

    def kill(self) -> None:
        self.process.send_signal(signal.SIGKILL)
        self.process.wait(10)

    def stop(self) -> None:
        if self.process.poll() is None:
            self.process.terminate()
            self.process.wait(10)


@pytest.fixture
def servers():
    started: list[Server] = []

    def start(*args: str) -> Server:
        started.append(Server(*args))
        return started[-1]

    yield start
    for server in started:
        server.stop()
