"""A headless Chromium driven over the DevTools protocol (websocket-client), for the viewer test.

Uses the Debian ``chromium`` package as installed; nothing is downloaded. WebGL (viser's
three.js canvas) runs on SwiftShader, Chromium's CPU renderer.
"""

from __future__ import annotations

import base64
import io
import json
import shutil
import socket
import subprocess
import tempfile
import time
import urllib.request
from pathlib import Path

import numpy as np

INSTALL_HINT = "headless Chromium is missing: run `apt-get install -y chromium chromium-driver`"


def chromium_path() -> str:
    """The Chromium executable; AssertionError with the install line when there is none."""
    found = shutil.which("chromium") or shutil.which("chromium-browser")
    assert found is not None, INSTALL_HINT
    return found


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def wait_for_http(url: str, proc: subprocess.Popen, log: Path, timeout: float) -> None:
    """Until ``url`` answers 200; fails with the server's log if ``proc`` ends or ``timeout`` passes."""
    deadline = time.time() + timeout
    while True:
        try:
            with urllib.request.urlopen(url, timeout=2) as response:
                if response.status == 200:
                    return
        except OSError:
            pass
        assert proc.poll() is None, f"the server exited ({proc.returncode}):\n{log.read_text()[-3000:]}"
        assert time.time() < deadline, f"the server did not serve {url} within {timeout:.0f} s:\n{log.read_text()[-3000:]}"
        time.sleep(0.5)


class Chromium:
    """One headless browser with one page; ``with Chromium() as page: page.open(url)``."""

    def __init__(self, width: int = 1200, height: int = 800) -> None:
        import websocket  # websocket-client, a nerfstudio dependency

        self.profile = tempfile.mkdtemp(prefix="idsplat_chromium_")
        port = free_port()
        self.proc = subprocess.Popen(
            [chromium_path(), "--headless=new", "--no-sandbox", "--no-first-run", "--disable-extensions",
             "--use-angle=swiftshader", "--enable-unsafe-swiftshader", f"--window-size={width},{height}",
             f"--remote-debugging-port={port}", "--remote-allow-origins=*",  # newer Chromium refuses the DevTools socket otherwise
             f"--user-data-dir={self.profile}", "about:blank"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        deadline = time.time() + 30
        while True:
            try:
                targets = json.load(urllib.request.urlopen(f"http://127.0.0.1:{port}/json", timeout=2))
                pages = [t for t in targets if t.get("type") == "page"]
                if pages:
                    break
            except OSError:
                pass
            assert self.proc.poll() is None, f"chromium exited with status {self.proc.returncode}"
            assert time.time() < deadline, "chromium did not open its DevTools port within 30 s"
            time.sleep(0.2)
        self.ws = websocket.create_connection(pages[0]["webSocketDebuggerUrl"], timeout=60)
        self._id = 0

    def __enter__(self) -> "Chromium":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        try:
            self.ws.close()
        finally:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
            shutil.rmtree(self.profile, ignore_errors=True)

    def call(self, method: str, **params) -> dict:
        self._id += 1
        self.ws.send(json.dumps({"id": self._id, "method": method, "params": params}))
        while True:
            message = json.loads(self.ws.recv())
            if message.get("id") == self._id:
                if "error" in message:
                    raise RuntimeError(f"{method}: {message['error']}")
                return message["result"]

    def open(self, url: str) -> None:
        self.call("Page.navigate", url=url)

    def js(self, expression: str):
        """The value of a JavaScript expression in the page."""
        result = self.call("Runtime.evaluate", expression=expression, returnByValue=True)
        if "exceptionDetails" in result:
            raise RuntimeError(f"javascript error: {result['exceptionDetails']}")
        return result["result"].get("value")

    def screenshot(self) -> np.ndarray:  # -> [H, W, 3] uint8
        from PIL import Image

        data = self.call("Page.captureScreenshot", format="png")["data"]
        return np.asarray(Image.open(io.BytesIO(base64.b64decode(data))).convert("RGB"))

    def wait_for(self, expression: str, timeout: float, what: str) -> None:
        deadline = time.time() + timeout
        guarded = f"(() => {{ try {{ return Boolean({expression}); }} catch (e) {{ return false; }} }})()"
        while not self.js(guarded):
            assert time.time() < deadline, f"timed out after {timeout:.0f} s waiting for {what}"
            time.sleep(0.25)

    def save(self, image: np.ndarray, path: Path) -> None:
        from PIL import Image

        Image.fromarray(image).save(path)
