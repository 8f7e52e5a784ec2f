"""A camera as an MJPEG stream over HTTP on 127.0.0.1 (``robot-sim --mjpeg PORT``): one JPEG part of a
``multipart/x-mixed-replace`` response per frame, as IP cameras serve and ``cv2.VideoCapture`` reads.
Only the newest frame is sent: a slow reader skips frames rather than falling behind."""

from __future__ import annotations

import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any

from ..errors import UsageError

_BOUNDARY = "hbvsframe"


class MjpegServer:
    """Serve the newest JPEG on ``http://127.0.0.1:port/`` until :meth:`close`."""

    def __init__(self, port: int) -> None:
        self._condition = threading.Condition()
        self._frame: bytes | None = None
        self._count = 0
        self._closed = False
        server = self

        class Handler(BaseHTTPRequestHandler):
            def do_GET(self) -> None:  # noqa: N802 - http.server's name
                self.send_response(200)
                self.send_header("Content-Type", f"multipart/x-mixed-replace; boundary={_BOUNDARY}")
                self.send_header("Cache-Control", "no-cache")
                self.end_headers()
                seen = 0
                try:
                    while True:
                        frame, seen = server._next(seen)
                        if frame is None:
                            return
                        self.wfile.write(f"--{_BOUNDARY}\r\nContent-Type: image/jpeg\r\nContent-Length: {len(frame)}\r\n\r\n".encode())
                        self.wfile.write(frame + b"\r\n")
                        self.wfile.flush()
                except (BrokenPipeError, ConnectionResetError):
                    return

            def log_message(self, format: str, *args: Any) -> None:  # noqa: A002 - quiet
                pass

        try:
            self._http = ThreadingHTTPServer(("127.0.0.1", port), Handler)
        except OSError as exc:
            raise UsageError(f"--mjpeg {port}: cannot listen on 127.0.0.1:{port} ({exc.strerror})") from None
        self._http.daemon_threads = True
        self._thread = threading.Thread(target=self._http.serve_forever, name="hbvs-mjpeg", daemon=True)
        self._thread.start()

    def _next(self, seen: int) -> tuple[bytes | None, int]:
        with self._condition:
            self._condition.wait_for(lambda: self._count != seen or self._closed)
            return (None if self._closed else self._frame), self._count

    def publish(self, jpeg: bytes) -> None:
        with self._condition:
            self._frame = jpeg
            self._count += 1
            self._condition.notify_all()

    def close(self) -> None:
        with self._condition:
            self._closed = True
            self._condition.notify_all()
        self._http.shutdown()
        self._http.server_close()
