"""Drive headless Chromium through the DevTools protocol over ``--remote-debugging-pipe`` (file
descriptors 3 and 4, NUL-terminated JSON messages): no websocket library, no downloaded browser.
Used by tests/test_web_example.py with Debian's chromium and its software WebGL2 (SwiftShader)."""

from __future__ import annotations

import fcntl
import json
import os
import shutil
import subprocess
import tempfile
import time

FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
         "--disable-background-networking", "--disable-component-update", "--disable-sync", "--no-first-run",
         "--remote-debugging-pipe"]


def chromium_path() -> str | None:
    return shutil.which("chromium") or shutil.which("chromium-browser")


class Chromium:
    """One headless browser; :meth:`open` a page, :meth:`evaluate` JavaScript in it; console
    messages and log entries are collected in :attr:`messages`."""

    def __init__(self) -> None:
        exe = chromium_path()
        if exe is None:
            raise RuntimeError("no chromium (apt-get install chromium)")
        self.profile = tempfile.mkdtemp(prefix="deformgl-chromium-")
        to_child_r, self._to_child = os.pipe()
        self._from_child, from_child_w = os.pipe()
        # the child's fd 3 reads commands, fd 4 writes replies (dup2 in the child)
        self.proc = subprocess.Popen(
            [exe, *FLAGS, f"--user-data-dir={self.profile}", "about:blank"], stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL, stderr=open(os.path.join(self.profile, 'stderr.txt'), 'wb'),
            close_fds=False, preexec_fn=_dup(to_child_r, from_child_w))  # (3, 4 are set in the child)
        os.close(to_child_r)
        os.close(from_child_w)
        self._buffer = b""
        self._id = 0
        self.messages: list[str] = []
        self.session: str | None = None

    def _send(self, method: str, params: dict | None = None, session: str | None = None) -> dict:
        self._id += 1
        msg: dict = {"id": self._id, "method": method, "params": params or {}}
        if session:
            msg["sessionId"] = session
        os.write(self._to_child, json.dumps(msg).encode() + b"\0")
        while True:
            reply = self._read()
            if reply.get("id") == self._id:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error']}")
                return reply.get("result", {})

    def _read(self) -> dict:
        while b"\0" not in self._buffer:
            chunk = os.read(self._from_child, 1 << 20)
            if not chunk:
                raise RuntimeError("chromium closed the DevTools pipe")
            self._buffer += chunk
        raw, self._buffer = self._buffer.split(b"\0", 1)
        msg = json.loads(raw)
        method = msg.get("method")
        if method == "Runtime.consoleAPICalled":
            args = msg["params"].get("args", [])
            self.messages.append(f"console.{msg['params'].get('type')}: " +
                                 " ".join(str(a.get("value", a.get("description", ""))) for a in args))
        elif method == "Log.entryAdded":
            e = msg["params"]["entry"]
            self.messages.append(f"log.{e.get('level')} ({e.get('source')}): {e.get('text')}")
        elif method == "Runtime.exceptionThrown":
            self.messages.append(f"exception: {msg['params']['exceptionDetails'].get('text')}")
        return msg

    def open(self, url: str) -> None:
        target = self._send("Target.createTarget", {"url": "about:blank"})["targetId"]
        self.session = self._send("Target.attachToTarget", {"targetId": target, "flatten": True})["sessionId"]
        for domain in ("Runtime.enable", "Log.enable", "Page.enable"):
            self._send(domain, session=self.session)
        self._send("Page.navigate", {"url": url}, session=self.session)

    def evaluate(self, expression: str):
        r = self._send("Runtime.evaluate", {"expression": expression, "returnByValue": True}, session=self.session)
        return r.get("result", {}).get("value")

    def mouse(self, kind: str, x: float, y: float) -> None:
        """A mouse event at CSS pixel (x, y) of the page: kind "pressed", "moved" or "released"."""
        self._send("Input.dispatchMouseEvent", {"type": f"mouse{kind.capitalize()}", "x": x, "y": y,
                                                "button": "left", "buttons": 0 if kind == "released" else 1,
                                                "clickCount": 1}, session=self.session)

    def wait_for(self, expression: str, timeout: float) -> object:
        """Poll until ``expression`` is truthy; returns its value."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            value = self.evaluate(expression)
            if value:
                return value
            time.sleep(0.2)
        raise TimeoutError(f"{expression!r} still false after {timeout} s; messages: {self.messages[-10:]}")

    def close(self) -> None:
        try:
            self._send("Browser.close")
        except Exception:
            pass
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        os.close(self._to_child)
        os.close(self._from_child)
        shutil.rmtree(self.profile, ignore_errors=True)


def _dup(read_fd: int, write_fd: int):
    def child() -> None:
        # move both out of the way first (either may be 3 or 4), then onto 3 and 4 (inheritable)
        high_r, high_w = fcntl.fcntl(read_fd, fcntl.F_DUPFD, 10), fcntl.fcntl(write_fd, fcntl.F_DUPFD, 10)
        os.dup2(high_r, 3)
        os.dup2(high_w, 4)
    return child


def edge_pixels(image):
    """(H, W) bool: pixels that differ from one of their 8 neighbours by more than 32/255 (the
    silhouette and crease pixels two rasterizers place differently)."""
    import numpy as np

    img = image.astype(int)
    pad = np.pad(img, ((1, 1), (1, 1), (0, 0)), mode="edge")
    h, w = img.shape[:2]
    out = np.zeros((h, w), bool)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            if dy or dx:
                out |= np.abs(pad[1 + dy:1 + dy + h, 1 + dx:1 + dx + w] - img).max(axis=2) > 32
    return out


def run_page(root, query: str, timeout: float = 120) -> dict:
    """Serve the folder ``root`` on localhost, open ``index.html?QUERY`` in headless Chromium
    and return the JSON the page writes into ``<pre id="result">``, with ``wall_s`` (the open to
    the result) and ``messages`` (the console and log entries)."""
    import functools
    import http.server
    import threading

    class Quiet(http.server.SimpleHTTPRequestHandler):
        def log_message(self, *args):
            pass

    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), functools.partial(Quiet, directory=str(root)))
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        browser = Chromium()
    except BaseException:
        server.shutdown()
        server.server_close()
        raise
    try:
        start = time.monotonic()
        browser.open(f"http://127.0.0.1:{server.server_port}/index.html?{query}")
        result = json.loads(browser.wait_for("document.getElementById('result').textContent", timeout))
        result["wall_s"] = time.monotonic() - start
        result["messages"] = list(browser.messages)
    finally:
        browser.close()
        server.shutdown()
        server.server_close()
    return result


def canvas_image(page: dict):
    """(H, W, 3) uint8: the page's canvas (its ``png`` data URL)."""
    import base64
    import io

    import numpy as np
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(base64.b64decode(page["png"].split(",", 1)[1]))).convert("RGB"))


def check_canvas(ours, web) -> str:
    """Assert the browser's frame ``web`` is deformgl's ``ours`` within the golden tolerances: at
    most 0.5 % of the pixels differ by more than 4/255, and no pixel by more than 64/255 away
    from edges. Silhouette and crease pixels (:func:`edge_pixels` of deformgl's frame) flip
    between the two rasterizers (llvmpipe and SwiftShader place sub-pixel edges differently), so
    the per-pixel limit leaves them out; they still count in the fraction. Returns the figures."""
    import numpy as np

    from deformgl.testing.imagediff import DEFAULT_CHANNEL_TOL, DEFAULT_MAX_FRACTION, DEFAULT_PIXEL_MAX

    assert web.shape == ours.shape, (web.shape, ours.shape)
    delta = np.abs(ours.astype(int) - web).max(axis=2)
    differ = (delta > DEFAULT_CHANNEL_TOL).mean()
    assert differ <= DEFAULT_MAX_FRACTION, differ
    edges = edge_pixels(ours)
    interior = delta[~edges]
    assert interior.max() <= DEFAULT_PIXEL_MAX, (interior.max(), np.argwhere((delta > DEFAULT_PIXEL_MAX) & ~edges)[:5])
    assert edges.mean() < 0.2  # the mask leaves most of the frame in the check
    assert (ours != ours[0, 0]).any(axis=2).mean() > 0.1  # the body fills the frame
    return (f"{differ:.4%} pixels over {DEFAULT_CHANNEL_TOL}/255; largest difference {delta.max()}/255, "
            f"{interior.max()}/255 away from edges ({edges.mean():.1%} of pixels are edges)")
