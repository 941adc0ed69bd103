"""Screenshot of the Rerun web viewer showing a recording (how ``docs/viewer.png`` is made).

    .venv/bin/sim_cluster up --scenario terrace-sim --topology chain --frames 300 \\
        --out runs/shot --quiet --rerun save runs/shot.rrd
    .venv/bin/python docs/viewer_screenshot.py runs/shot.rrd docs/viewer.png

Serves the file with Rerun's own web viewer (``rerun --serve-web FILE``, loopback), opens it in
headless Chromium (WebGL2 on SwiftShader), waits until the viewer has loaded, and captures the
page over Chromium's DevTools protocol (``--screenshot`` fires before the viewer has drawn).
Needs ``chromium`` on the PATH. Standard library only: a minimal WebSocket client is below.
"""
from __future__ import annotations

import argparse
import base64
import json
import os
import shutil
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_http(url: str, timeout: float) -> bytes:
    deadline = time.time() + timeout
    while True:
        try:
            with urllib.request.urlopen(url, timeout=2) as r:
                return r.read()
        except OSError:
            if time.time() > deadline:
                raise
            time.sleep(0.3)


class WebSocket:
    """Just enough RFC 6455 for the DevTools protocol: text frames, client masking."""

    def __init__(self, url: str):
        assert url.startswith("ws://")
        hostport, _, path = url[5:].partition("/")
        host, _, port = hostport.partition(":")
        self.sock = socket.create_connection((host, int(port)), timeout=60)
        key = base64.b64encode(os.urandom(16)).decode()
        self.sock.sendall((f"GET /{path} HTTP/1.1\r\nHost: {hostport}\r\nUpgrade: websocket\r\n"
                           f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\n"
                           "Sec-WebSocket-Version: 13\r\n\r\n").encode())
        head = b""
        while b"\r\n\r\n" not in head:
            head += self.sock.recv(1)
        if b" 101 " not in head.split(b"\r\n")[0]:
            raise OSError(f"websocket handshake failed: {head[:200]!r}")
        self._id = 0

    def _recv_exact(self, n: int) -> bytes:
        buf = bytearray()
        while len(buf) < n:
            chunk = self.sock.recv(n - len(buf))
            if not chunk:
                raise OSError("websocket closed")
            buf += chunk
        return bytes(buf)

    def send(self, text: str) -> None:
        data = text.encode()
        head = bytearray([0x81])
        n = len(data)
        if n < 126:
            head.append(0x80 | n)
        elif n < 65536:
            head += bytes([0x80 | 126]) + struct.pack(">H", n)
        else:
            head += bytes([0x80 | 127]) + struct.pack(">Q", n)
        mask = os.urandom(4)
        self.sock.sendall(bytes(head) + mask + bytes(b ^ mask[i % 4] for i, b in enumerate(data)))

    def recv(self) -> str:
        parts = []
        while True:
            b0, b1 = self._recv_exact(2)
            n = b1 & 0x7F
            if n == 126:
                n = struct.unpack(">H", self._recv_exact(2))[0]
            elif n == 127:
                n = struct.unpack(">Q", self._recv_exact(8))[0]
            parts.append(self._recv_exact(n))
            if b0 & 0x80:  # FIN
                return b"".join(parts).decode()

    def call(self, method: str, **params) -> dict:
        self._id += 1
        self.send(json.dumps({"id": self._id, "method": method, "params": params}))
        while True:
            msg = json.loads(self.recv())
            if msg.get("id") == self._id:
                if "error" in msg:
                    raise OSError(f"{method}: {msg['error']}")
                return msg.get("result", {})


class FileServer:
    """One file over HTTP on loopback, with CORS (the viewer runs on another port)."""

    def __init__(self, path: Path):
        import http.server
        import threading

        data = path.read_bytes()

        class Handler(http.server.BaseHTTPRequestHandler):
            def do_GET(self):  # noqa: N802
                self.send_response(200)
                self.send_header("Access-Control-Allow-Origin", "*")
                self.send_header("Content-Type", "application/octet-stream")
                self.send_header("Content-Length", str(len(data)))
                self.end_headers()
                self.wfile.write(data)

            def log_message(self, *a):
                pass

        self.httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.url = f"http://127.0.0.1:{self.httpd.server_address[1]}/{path.name}"
        threading.Thread(target=self.httpd.serve_forever, daemon=True).start()

    def close(self) -> None:
        self.httpd.shutdown()


def rerun_binary() -> str:
    import rerun_cli

    return str(Path(rerun_cli.__file__).parent / "rerun")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("rrd")
    ap.add_argument("png")
    ap.add_argument("--wait", type=float, default=25.0, help="seconds to let the viewer load")
    ap.add_argument("--size", default="1600,1000")
    a = ap.parse_args(argv)
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    if chromium is None:
        print("chromium not found (apt-get install chromium)", file=sys.stderr)
        return 1
    grpc, web, devtools = free_port(), free_port(), free_port()
    procs = []
    profile = tempfile.mkdtemp(prefix="viewer-shot-")
    files = FileServer(Path(a.rrd))
    try:
        # the viewer's web app from rerun; the file itself over plain HTTP, so that the viewer
        # loads it whole (streamed through a gRPC proxy it arrives slowly here)
        procs.append(subprocess.Popen(
            [rerun_binary(), "--serve-web", "--bind", "127.0.0.1", "--port", str(grpc),
             "--web-viewer-port", str(web)],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True))
        wait_http(f"http://127.0.0.1:{web}/", 30)
        url = f"http://127.0.0.1:{web}/?url={files.url}"
        w, h = a.size.split(",")
        procs.append(subprocess.Popen(
            [chromium, "--headless=new", "--no-sandbox", "--use-gl=angle",
             "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist",
             "--hide-scrollbars", f"--window-size={w},{h}", f"--user-data-dir={profile}",
             f"--remote-debugging-port={devtools}", "--remote-allow-origins=*", url],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True))
        wait_http(f"http://127.0.0.1:{devtools}/json/version", 30)
        pages = [p for p in json.loads(wait_http(f"http://127.0.0.1:{devtools}/json", 10))
                 if p.get("type") == "page"]
        ws = WebSocket(pages[0]["webSocketDebuggerUrl"])
        time.sleep(a.wait)
        shot = ws.call("Page.captureScreenshot", format="png")
        Path(a.png).parent.mkdir(parents=True, exist_ok=True)
        Path(a.png).write_bytes(base64.b64decode(shot["data"]))
        print(f"wrote {a.png} ({url})")
        return 0
    finally:
        for p in procs:  # each in its own session: end the whole group (rerun's children too)
            try:
                os.killpg(p.pid, signal.SIGTERM)
            except ProcessLookupError:
                pass
        for p in procs:
            try:
                p.wait(10)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
        shutil.rmtree(profile, ignore_errors=True)
        files.close()


if __name__ == "__main__":
    sys.exit(main())
