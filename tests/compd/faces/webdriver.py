"""A small W3C WebDriver client (the standard library only) for Debian's
chromium and chromedriver, for the status page's browser test. Selenium would
do the same but pulls trio, whose hypothesis plugin breaks the test run
(warnings are errors)."""

from __future__ import annotations

import base64
import contextlib
import json
import shutil
import subprocess
import time
import urllib.error
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from drivers.sim.ports import free_tcp_port

CHROMIUM = "/usr/bin/chromium"
CHROMEDRIVER = "/usr/bin/chromedriver"


def browser_missing() -> str | None:
    """Why the browser test cannot run here, None when it can."""
    for path, package in ((CHROMIUM, "chromium"), (CHROMEDRIVER, "chromium-driver")):
        if not (Path(path).exists() or shutil.which(Path(path).name)):
            return f"{path} absent: apt-get install {package}"
    return None


class Browser:
    """One headless chromium session driven through chromedriver on 127.0.0.1."""

    def __init__(self, base: str, session: str) -> None:
        self._base = base
        self._session = session

    def _call(self, method: str, path: str, body: dict[str, Any] | None = None,
              timeout_s: float = 30.0) -> Any:
        return _request(method, f"{self._base}/session/{self._session}{path}", body, timeout_s)

    def get(self, url: str) -> None:
        self._call("POST", "/url", {"url": url})

    def script(self, source: str) -> Any:
        """The value of `source` (a function body: ``return ...``) in the page."""
        return self._call("POST", "/execute/sync", {"script": source, "args": []})

    def screenshot(self, path: Path) -> Path:
        path.write_bytes(base64.b64decode(self._call("GET", "/screenshot")))
        return path

    def wait_for(self, source: str, timeout_s: float = 20.0) -> Any:
        """Poll `source` until it returns something truthy (AssertionError after timeout)."""
        deadline = time.monotonic() + timeout_s
        while True:
            value = self.script(source)
            if value:
                return value
            if time.monotonic() > deadline:
                raise AssertionError(f"browser: not reached: {source}")
            time.sleep(0.1)


def _request(method: str, url: str, body: dict[str, Any] | None, timeout_s: float) -> Any:
    data = None if body is None else json.dumps(body).encode()
    req = urllib.request.Request(url, data=data, method=method,
                                 headers={"Content-Type": "application/json"})
    try:
        with urllib.request.urlopen(req, timeout=timeout_s) as resp:
            return json.loads(resp.read())["value"]
    except urllib.error.HTTPError as exc:
        raise AssertionError(f"webdriver {method} {url}: {exc.read()[:500]!r}") from None


@contextlib.contextmanager
def headless_chromium(width: int = 1200, height: int = 1500) -> Iterator[Browser]:
    port = free_tcp_port("127.0.0.1")
    driver = subprocess.Popen([CHROMEDRIVER, f"--port={port}", "--allowed-ips=127.0.0.1"],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    base = f"http://127.0.0.1:{port}"
    try:
        for _ in range(200):
            with contextlib.suppress(OSError, ValueError, AssertionError):
                if _request("GET", f"{base}/status", None, 1.0).get("ready"):
                    break
            time.sleep(0.05)
        caps = {"capabilities": {"alwaysMatch": {
            "browserName": "chrome", "goog:chromeOptions": {
                "binary": CHROMIUM,
                "args": ["--headless=new", "--no-sandbox", "--disable-gpu",
                         "--disable-dev-shm-usage", "--no-first-run",
                         f"--window-size={width},{height}"]}}}}
        session = _request("POST", f"{base}/session", caps, 60.0)["sessionId"]
        browser = Browser(base, session)
        try:
            yield browser
        finally:
            with contextlib.suppress(OSError, AssertionError):
                _request("DELETE", f"{base}/session/{session}", None, 10.0)
    finally:
        driver.terminate()
        try:
            driver.wait(10.0)
        except subprocess.TimeoutExpired:
            driver.kill()
            driver.wait()
