"""The local server of `npga-view web`: the project's page (`npga_view/web/`), LAM's web player (`web_player.py`),
one avatar zip and the ARKit weights that drive it, on 127.0.0.1 only, nothing else.

Routes (GET): ``/`` and ``/index.html``, ``/page.js``, ``/player/NAME`` (a file of the player's build folder, no
sub-folders), ``/avatar.zip``, ``/config.json`` (what the page plays: ``{"zip", "take", "live"}``), ``/take.json``
(a take resampled at its own rate: ``{"fps", "names", "frames"}``, weights over ARKit's 52 names) and
``/live?after=SEQ`` (a long poll: answers at once when the newest Live Link packet is newer than SEQ, else when
one arrives or after `LONG_POLL_S`: ``{"seq", "weights": {name: value}}``; seq 0 and no weights before the first
packet). Every other path is a 404; no directory listing, no file outside these.
"""

from __future__ import annotations

import json
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any
from urllib.parse import parse_qs, urlsplit

import numpy as np

from npga_core.files.blendshape_names import ARKIT_52
from npga_view.web_player import PAGE

#: The longest a /live request waits for a newer packet (seconds).
LONG_POLL_S = 10.0
TYPES = {".html": "text/html; charset=utf-8", ".js": "text/javascript; charset=utf-8", ".json": "application/json",
         ".map": "application/json", ".zip": "application/zip", ".wasm": "application/wasm"}


def take_document(path: str | Path) -> dict:
    """A take (Live Link Face .csv, ARKit .json) as the page plays it: its weights over ARKit's 52 names on its
    own frame grid (AvatarFileError, one line, for a bad file or one that names no ARKit shape)."""
    from npga_core.errors import AvatarFileError
    from npga_core.files.arkit_takes import read_take, resampled
    from npga_core.files.blendshape_names import match_names

    take = read_take(path)
    try:
        match = match_names(take.names, ARKIT_52)
    except ValueError as e:
        raise AvatarFileError(path, str(e)) from None
    grid = resampled(take, list(range(len(take.names))), path)
    weights = np.clip(np.nan_to_num(match.apply(grid)), -10.0, 10.0)
    return {"fps": float(take.fps), "names": list(ARKIT_52),
            "frames": [[round(float(v), 4) for v in row] for row in weights]}


class LiveWeights:
    """The newest weights of a Live Link receiver, numbered, for long polls."""

    def __init__(self, receiver: Any):
        self.receiver = receiver
        self.seq = 0
        self.weights: dict[str, float] = {}
        self.cond = threading.Condition()
        receiver.on_packet = self._packet

    def _packet(self) -> None:
        newest = self.receiver.latest()
        if newest is None:
            return
        w = newest[0]
        with self.cond:
            self.seq += 1
            self.weights = {n: round(float(v), 4) for n, v in zip(ARKIT_52, w, strict=True)}
            self.cond.notify_all()

    def wait(self, after: int, timeout: float = LONG_POLL_S) -> dict:
        with self.cond:
            self.cond.wait_for(lambda: self.seq > after, timeout)
            return {"seq": self.seq, "weights": dict(self.weights)}


class WebServer:
    """The server, serving on its own thread until `close()`."""

    def __init__(self, zip_path: Path, player: Path, port: int, take: dict | None = None,
                 live: LiveWeights | None = None, host: str = "127.0.0.1"):
        self.zip_path, self.player, self.take, self.live = zip_path, player, take, live
        config = {"zip": "avatar.zip", "take": "take.json" if take is not None else None,
                  "live": "live" if live is not None else None}
        self.config = json.dumps(config).encode()
        self.take_bytes = json.dumps(take).encode() if take is not None else b""
        self.requests: list[str] = []
        self.httpd = ThreadingHTTPServer((host, port), self._handler())
        self.httpd.daemon_threads = True
        self.port = int(self.httpd.server_address[1])
        self.url = f"http://{host}:{self.port}/"
        self.thread = threading.Thread(target=self.httpd.serve_forever, name="npga-web", daemon=True)
        self.thread.start()

    def body(self, path: str, query: str) -> tuple[bytes, str] | None:
        """The bytes and type of a GET, None for a 404."""
        if path in ("/", "/index.html"):
            return (PAGE / "index.html").read_bytes(), TYPES[".html"]
        if path == "/page.js":
            return (PAGE / "page.js").read_bytes(), TYPES[".js"]
        if path == "/config.json":
            return self.config, TYPES[".json"]
        if path == "/avatar.zip":
            return self.zip_path.read_bytes(), TYPES[".zip"]
        if path == "/take.json" and self.take is not None:
            return self.take_bytes, TYPES[".json"]
        if path == "/live" and self.live is not None:
            after = parse_qs(query).get("after", ["0"])[0]
            doc = self.live.wait(int(after) if after.isdigit() and len(after) < 18 else 0)
            return json.dumps(doc).encode(), TYPES[".json"]
        name = path[len("/player/"):]
        if path.startswith("/player/") and name and "/" not in name and "\\" not in name and not name.startswith("."):
            src = self.player / name
            if src.is_file():
                return src.read_bytes(), TYPES.get(src.suffix, "application/octet-stream")
        return None

    def _handler(self) -> type[BaseHTTPRequestHandler]:
        server = self

        class Handler(BaseHTTPRequestHandler):
            def log_message(self, *args: Any) -> None:  # quiet: the command prints its own lines
                pass

            def do_GET(self) -> None:  # noqa: N802 - http.server's name
                parts = urlsplit(self.path)
                server.requests.append(parts.path)
                try:
                    found = server.body(parts.path, parts.query)
                except OSError:
                    found = None
                if found is None:
                    self.send_error(404)
                    return
                data, kind = found
                self.send_response(200)
                self.send_header("Content-Type", kind)
                self.send_header("Content-Length", str(len(data)))
                self.send_header("Cache-Control", "no-store")
                self.end_headers()
                self.wfile.write(data)

        return Handler

    def close(self) -> None:
        self.httpd.shutdown()
        self.httpd.server_close()
