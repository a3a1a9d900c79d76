"""A headless Chromium driven over the DevTools protocol, for tests of pages eponet writes (standard library only:
a minimal websocket client, enough for DevTools' unfragmented text frames)."""

from __future__ import annotations

import base64
import json
import os
import select
import shutil
import socket
import struct
import subprocess
import tempfile
import time
import urllib.request
from pathlib import Path

__all__ = ["chromium_binary", "Chromium", "PageLoad"]

#: Debian's package installs ``chromium``; other distributions use the other names.
_BINARIES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")


def chromium_binary() -> str | None:
    """The Chromium on ``$PATH`` (or ``$EPONET_CHROMIUM``), ``None`` when there is none."""
    given = os.environ.get("EPONET_CHROMIUM")
    if given:
        return shutil.which(given) or (given if Path(given).is_file() else None)
    for name in _BINARIES:
        path = shutil.which(name)
        if path:
            return path
    return None


class _WebSocket:
    """Client side of RFC 6455 over a plain TCP socket: masked text frames out, frames in (pings answered)."""

    def __init__(self, url: str, timeout: float):
        assert url.startswith("ws://"), url
        host_port, _, path = url[len("ws://"):].partition("/")
        host, _, port = host_port.partition(":")
        self.sock = socket.create_connection((host, int(port or 80)), timeout=timeout)
        key = base64.b64encode(os.urandom(16)).decode()
        self.sock.sendall((f"GET /{path} HTTP/1.1\r\nHost: {host_port}\r\nUpgrade: websocket\r\n"
                           f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n\r\n").encode())
        response = b""
        while b"\r\n\r\n" not in response:
            chunk = self.sock.recv(4096)
            if not chunk:
                raise ConnectionError("websocket handshake: connection closed")
            response += chunk
        head, _, self._buffer = response.partition(b"\r\n\r\n")
        if b" 101 " not in head.split(b"\r\n")[0]:
            raise ConnectionError(f"websocket handshake refused: {head.splitlines()[0]!r}")

    def _read(self, size: int) -> bytes:
        while len(self._buffer) < size:
            chunk = self.sock.recv(max(65536, size - len(self._buffer)))
            if not chunk:
                raise ConnectionError("websocket: connection closed")
            self._buffer += chunk
        data, self._buffer = self._buffer[:size], self._buffer[size:]
        return data

    def _send_frame(self, opcode: int, payload: bytes) -> None:
        header = bytes([0x80 | opcode])
        size = len(payload)
        if size < 126:
            header += bytes([0x80 | size])
        elif size < 2**16:
            header += bytes([0x80 | 126]) + struct.pack("!H", size)
        else:
            header += bytes([0x80 | 127]) + struct.pack("!Q", size)
        mask = os.urandom(4)
        self.sock.sendall(header + mask + bytes(b ^ mask[k % 4] for k, b in enumerate(payload)))

    def send(self, text: str) -> None:
        self._send_frame(0x1, text.encode())

    def receive(self) -> str:
        message = b""
        while True:
            first, second = self._read(2)
            opcode, size = first & 0x0F, second & 0x7F
            if size == 126:
                size = struct.unpack("!H", self._read(2))[0]
            elif size == 127:
                size = struct.unpack("!Q", self._read(8))[0]
            mask = self._read(4) if second & 0x80 else None
            payload = self._read(size)
            if mask:
                payload = bytes(b ^ mask[k % 4] for k, b in enumerate(payload))
            if opcode == 0x9:  # ping
                self._send_frame(0xA, payload)
                continue
            if opcode == 0x8:
                raise ConnectionError("websocket: closed by the browser")
            message += payload
            if first & 0x80:  # FIN
                return message.decode()

    def pending(self) -> bool:
        return bool(self._buffer)

    def close(self) -> None:
        try:
            self._send_frame(0x8, b"")
        except OSError:
            pass
        self.sock.close()


class PageLoad:
    """What loading a page showed: ``errors`` (console errors, uncaught exceptions, failed resources, one line
    each), ``media`` (per ``<video>``: ``duration``, ``error`` code or ``None``, ``width``, ``height``), ``images``
    (per ``<img>``: ``src`` and ``natural_width``, 0 when it did not load) and the ``screenshot`` (PNG bytes)."""

    def __init__(self, errors: list[str], media: list[dict], images: list[dict], screenshot: bytes):
        self.errors, self.media, self.images, self.screenshot = errors, media, images, screenshot


#: Run in the page after its load event: waits (at most ``timeout_ms``) until every video has its metadata or an
#: error, then describes the videos and images.
_PROBE = """
new Promise(resolve => {
  const videos = [...document.querySelectorAll('video')];
  const describe = () => ({
    media: videos.map(v => ({duration: Number.isFinite(v.duration) ? v.duration : String(v.duration),
                             error: v.error ? v.error.code : null, width: v.videoWidth, height: v.videoHeight})),
    images: [...document.images].map(i => ({src: i.getAttribute('src').slice(0, 80), natural_width: i.naturalWidth}))
  });
  const settled = () => videos.every(v => v.readyState >= 1 || v.error);
  const start = Date.now();
  (function wait() {
    if (settled() || Date.now() - start > TIMEOUT_MS) resolve(JSON.stringify(describe()));
    else setTimeout(wait, 50);
  })();
})
"""


class Chromium:
    """A headless Chromium with its own profile and a DevTools port; a context manager (the browser ends on
    exit). ``load(path)`` opens a local file and reports a :class:`PageLoad`."""

    def __init__(self, binary: str, *, timeout: float = 60.0, window: tuple[int, int] = (1280, 1600)):
        self.binary, self.timeout, self.window = binary, timeout, window

    def __enter__(self) -> "Chromium":
        self.profile = tempfile.mkdtemp(prefix="eponet-chromium-")
        self.process = subprocess.Popen(
            [self.binary, "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run", "--no-default-browser-check",
             "--disable-extensions", "--mute-audio", "--hide-scrollbars", f"--user-data-dir={self.profile}",
             "--remote-debugging-port=0", f"--window-size={self.window[0]},{self.window[1]}", "about:blank"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            self.port = self._devtools_port()
        except BaseException:
            self.__exit__(None, None, None)
            raise
        return self

    def _devtools_port(self) -> int:
        # with --remote-debugging-port=0 Chromium picks a free port and writes it into the profile
        marker = Path(self.profile) / "DevToolsActivePort"
        deadline = time.monotonic() + self.timeout
        while time.monotonic() < deadline:
            if self.process.poll() is not None:
                raise RuntimeError(f"{self.binary} exited with code {self.process.returncode} at start")
            if marker.is_file() and marker.read_text().strip():
                return int(marker.read_text().split()[0])
            time.sleep(0.1)
        raise TimeoutError(f"{self.binary}: no DevTools port after {self.timeout:.0f} s")

    def __exit__(self, *exc) -> None:
        if self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        shutil.rmtree(self.profile, ignore_errors=True)

    def load(self, path: str | Path, *, media_timeout_ms: int = 15000) -> PageLoad:
        with urllib.request.urlopen(f"http://127.0.0.1:{self.port}/json/list", timeout=self.timeout) as response:
            targets = [t for t in json.load(response) if t.get("type") == "page"]
        socket_ = _WebSocket(targets[0]["webSocketDebuggerUrl"], self.timeout)
        session = _Session(socket_, self.timeout)
        try:
            for method in ("Runtime.enable", "Log.enable", "Page.enable"):
                session.call(method)
            session.call("Page.navigate", url=Path(path).resolve().as_uri())
            session.wait_for("Page.loadEventFired")
            probe = session.call("Runtime.evaluate", expression=_PROBE.replace("TIMEOUT_MS", str(media_timeout_ms)),
                                 awaitPromise=True, returnByValue=True)
            found = json.loads(probe["result"]["value"])
            shot = session.call("Page.captureScreenshot", format="png")
            session.drain(0.3)  # late console messages (e.g. a failed resource after load)
            return PageLoad(session.errors(), found["media"], found["images"], base64.b64decode(shot["data"]))
        finally:
            socket_.close()


class _Session:
    """DevTools calls (``call`` waits for its answer) with every event kept, in order."""

    def __init__(self, socket_: _WebSocket, timeout: float):
        self.socket, self.timeout, self.events, self._id = socket_, timeout, [], 0

    def call(self, method: str, **params) -> dict:
        self._id += 1
        self.socket.send(json.dumps({"id": self._id, "method": method, "params": params}))
        while True:
            message = json.loads(self.socket.receive())
            if message.get("id") == self._id:
                if "error" in message:
                    raise RuntimeError(f"DevTools {method}: {message['error']}")
                return message.get("result", {})
            self.events.append(message)

    def wait_for(self, event: str) -> None:
        deadline = time.monotonic() + self.timeout
        while not any(e.get("method") == event for e in self.events):
            if time.monotonic() > deadline:
                raise TimeoutError(f"DevTools: no {event} after {self.timeout:.0f} s")
            self.events.append(json.loads(self.socket.receive()))

    def drain(self, seconds: float) -> None:
        """Keep the events that arrive within ``seconds`` (whole messages only)."""
        while self.socket.pending() or select.select([self.socket.sock], [], [], seconds)[0]:
            self.events.append(json.loads(self.socket.receive()))

    def errors(self) -> list[str]:
        lines = []
        for event in self.events:
            method, params = event.get("method"), event.get("params", {})
            if method == "Runtime.consoleAPICalled" and params.get("type") in ("error", "assert"):
                values = (a.get("value", a.get("description", "")) for a in params.get("args", []))
                lines.append("console: " + " ".join(map(str, values)))
            elif method == "Runtime.exceptionThrown":
                details = params.get("exceptionDetails", {})
                lines.append("exception: " + str(details.get("exception", {}).get("description") or details.get("text")))
            elif method == "Log.entryAdded" and params.get("entry", {}).get("level") == "error":
                entry = params["entry"]
                lines.append(f"log ({entry.get('source')}): {entry.get('text')} {entry.get('url', '')}".rstrip())
        return lines
