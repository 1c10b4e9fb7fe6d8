"""Headless Chromium driven through the DevTools protocol, for tests that look at a web viewer's page.

`screenshot(url, ready)` opens `url` in a fresh headless Chromium (Debian's ``chromium`` package), waits until a
screenshot of the page satisfies `ready` (e.g. `distinct_colours` of the area where a 3D view draws, a loading
screen has a handful) and returns it as PNG bytes. The protocol is spoken over a minimal WebSocket client of the standard
library (text frames, one connection), so no driver package is needed.
"""

from __future__ import annotations

import base64
import contextlib
import io
import json
import os
import shutil
import signal
import socket
import struct
import subprocess
import tempfile
import time
import urllib.request
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

__all__ = ["CHROMIUM", "chromium_missing", "screenshot", "pixels", "distinct_colours"]

CHROMIUM = os.environ.get("SIMREEL_CHROMIUM", "/usr/bin/chromium")
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync", "--mute-audio"]
"""Flags that work on a machine without a GPU or a display (software rendering: WebGL through SwiftShader)."""


def chromium_missing() -> str | None:
    """Why no headless browser can run here (None: one can)."""
    if not (Path(CHROMIUM).is_file() and os.access(CHROMIUM, os.X_OK)) and shutil.which(CHROMIUM) is None:
        return f"no Chromium at {CHROMIUM} (apt-get install chromium; `make test-setup` does it as root)"
    return None


WINDOW = (1280, 800)
"""The browser window's size (the page is a little shorter: the headless window keeps room for its frame)."""


def screenshot(url: str, ready: Callable[[bytes], bool], *, timeout_s: float = 40.0, settle_s: float = 2.0) -> bytes:
    """The page at `url` once `ready(png)` holds for a screenshot, and `settle_s` later (the stream still arriving);
    the last screenshot taken when `timeout_s` passes first."""
    with _browser(*WINDOW) as tab:
        tab.call("Page.enable")
        tab.call("Page.navigate", url=url)
        deadline = time.monotonic() + timeout_s
        shot = tab.screenshot()
        while not ready(shot) and time.monotonic() < deadline:
            time.sleep(1.0)
            shot = tab.screenshot()
        if ready(shot):
            time.sleep(settle_s)
            shot = tab.screenshot()
        return shot


def pixels(png: bytes) -> np.ndarray:
    """The screenshot as an (height, width, 3) uint8 array."""
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))


def distinct_colours(png: bytes, *, box: tuple[float, float, float, float] = (0.3, 0.3, 0.7, 0.7)) -> int:
    """How many distinct RGB colours (to 4 bits a channel) the screenshot has in `box` (fractions of the page)."""
    image = pixels(png)
    height, width = image.shape[:2]
    part = image[int(box[1] * height):int(box[3] * height), int(box[0] * width):int(box[2] * width)] >> 4
    return len(np.unique(part.reshape(-1, 3).astype(np.int32) @ np.array([256, 16, 1])))


class _Tab:
    """One DevTools page connection: `call` sends a command and returns its result (events are skipped)."""

    def __init__(self, sock: socket.socket) -> None:
        self.sock, self.next_id = sock, 0

    def call(self, method: str, **params: object) -> dict:
        self.next_id += 1
        _send_text(self.sock, json.dumps({"id": self.next_id, "method": method, "params": params}))
        while True:
            message = json.loads(_receive_text(self.sock))
            if message.get("id") == self.next_id:
                if "error" in message:
                    raise RuntimeError(f"{method}: {message['error']}")
                return message.get("result", {})

    def screenshot(self) -> bytes:
        """The page as PNG; while a navigation has not attached the page yet, tried again for a few seconds."""
        for attempt in range(20):
            try:
                return base64.b64decode(self.call("Page.captureScreenshot", format="png")["data"])
            except RuntimeError:
                if attempt == 19:
                    raise
                time.sleep(0.5)
        raise AssertionError("unreachable")


@contextlib.contextmanager
def _browser(width: int, height: int) -> Iterator[_Tab]:
    with tempfile.TemporaryDirectory(prefix="simreel-chromium-", ignore_cleanup_errors=True) as profile:
        port = _free_port()
        process = subprocess.Popen([CHROMIUM, *FLAGS, f"--user-data-dir={profile}", f"--remote-debugging-port={port}",
                                    f"--window-size={width},{height}", "about:blank"],
                                   stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                   start_new_session=True)
        try:
            with _page_socket(port) as sock:
                yield _Tab(sock)
        finally:  # the browser and the renderer, GPU and utility processes it started: its whole group
            os.killpg(process.pid, signal.SIGTERM)
            try:
                process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                os.killpg(process.pid, signal.SIGKILL)
                process.wait()
            time.sleep(0.5)  # its children leave the profile folder


@contextlib.contextmanager
def _page_socket(port: int, *, timeout_s: float = 20.0) -> Iterator[socket.socket]:
    """A WebSocket connection to the browser's first page target."""
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=2) as answer:
                pages = [t for t in json.load(answer) if t.get("type") == "page"]
            if pages:
                break
        except OSError:
            pass
        if time.monotonic() > deadline:
            raise RuntimeError(f"Chromium's DevTools did not answer on port {port}")
        time.sleep(0.2)
    path = pages[0]["webSocketDebuggerUrl"].split(f":{port}", 1)[1]
    sock = socket.create_connection(("127.0.0.1", port), timeout=30)
    key = base64.b64encode(os.urandom(16)).decode()
    sock.sendall((f"GET {path} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                  f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n\r\n").encode())
    answer = b""
    while b"\r\n\r\n" not in answer:
        answer += sock.recv(4096)
    if b" 101 " not in answer.split(b"\r\n", 1)[0]:
        raise RuntimeError(f"DevTools refused the WebSocket: {answer.splitlines()[0]!r}")
    try:
        yield sock
    finally:
        sock.close()


def _send_text(sock: socket.socket, text: str) -> None:
    data, mask = text.encode(), os.urandom(4)
    header = bytes([0x81])
    if len(data) < 126:
        header += bytes([0x80 | len(data)])
    elif len(data) < 65536:
        header += bytes([0x80 | 126]) + struct.pack(">H", len(data))
    else:
        header += bytes([0x80 | 127]) + struct.pack(">Q", len(data))
    sock.sendall(header + mask + bytes(b ^ mask[i % 4] for i, b in enumerate(data)))


def _receive_text(sock: socket.socket) -> str:
    """One whole message (continuation frames joined); the server's frames are not masked."""
    parts = []
    while True:
        first, second = _read(sock, 2)
        length = second & 0x7F
        if length == 126:
            length = struct.unpack(">H", _read(sock, 2))[0]
        elif length == 127:
            length = struct.unpack(">Q", _read(sock, 8))[0]
        parts.append(_read(sock, length))
        if first & 0x80:
            return b"".join(parts).decode()


def _read(sock: socket.socket, n: int) -> bytes:
    data = bytearray()
    while len(data) < n:
        chunk = sock.recv(min(n - len(data), 1 << 20))
        if not chunk:
            raise RuntimeError("DevTools closed the connection")
        data += chunk
    return bytes(data)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]
