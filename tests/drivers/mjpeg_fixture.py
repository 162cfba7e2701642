"""A tiny MJPEG-over-HTTP camera for the camera seam's tests (no twin, no physics).

Why its own server: the drain, the timeouts and the busy answer of a network camera need
a camera whose every frame says when it was made and whose failures can be switched on;
the hardware twin's stream (tests in test_yumi_seams.py) shows a real world, this one
shows time. Each frame carries its number as 16 black/white 16 px blocks (survives JPEG);
``produced[n]`` is the monotonic time frame n was made. Frames are paced from the end of
the previous send (as a camera that drops frames while its client stalls), so a stalled
client finds stale frames queued in the sockets, as with a real IP camera.
"""

from __future__ import annotations

import socket
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any

import numpy as np

BLOCK = 16
BITS = 16


def stamp(n: int, size: tuple[int, int] = (320, 240)) -> np.ndarray:
    import cv2

    w, h = size
    img = np.full((h, w, 3), 90, np.uint8)
    for b in range(BITS):
        if n >> b & 1:
            img[:BLOCK, b * BLOCK:(b + 1) * BLOCK] = 255
        else:
            img[:BLOCK, b * BLOCK:(b + 1) * BLOCK] = 0
    cv2.putText(img, str(n), (20, 150), cv2.FONT_HERSHEY_SIMPLEX, 2.0, (255, 255, 255), 4)
    return img


def frame_number(img: np.ndarray) -> int:
    row = img[BLOCK // 2, BLOCK // 2::BLOCK][:BITS].mean(axis=-1)
    return int(sum(1 << b for b, v in enumerate(row) if v > 128))


class MjpegCamera:
    """``with MjpegCamera(fps) as cam: cam.url``; ``busy``/``mute``/``stall``/``frozen``
    switch failures on: 503 "camera busy" to a new client, accept and say nothing, stop
    sending frames, send the same frame over and over (an encoder that hung)."""

    def __init__(self, fps: float = 15.0, size: tuple[int, int] = (320, 240)) -> None:
        self.fps = fps
        self.size = size
        self.produced: dict[int, float] = {}
        self.busy = False
        self.mute = False
        self.stall = threading.Event()
        self.frozen = threading.Event()
        self._jpg = b""
        self._stop = threading.Event()
        self._count = 0
        cam = self

        class Handler(BaseHTTPRequestHandler):
            def log_message(self, *a: Any) -> None:
                pass

            def do_GET(self) -> None:
                cam._serve(self)

        self._server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self._server.daemon_threads = True
        self.port = self._server.server_address[1]
        self.url = f"http://127.0.0.1:{self.port}/camera.mjpg"
        self._thread = threading.Thread(target=self._server.serve_forever, daemon=True)

    def _serve(self, h: BaseHTTPRequestHandler) -> None:
        import cv2

        if self.mute:
            self._stop.wait(30)
            return
        if self.busy:
            body = b"camera busy: another client is streaming\n"
            h.send_response(503)
            h.send_header("Content-Type", "text/plain")
            h.send_header("Content-Length", str(len(body)))
            h.end_headers()
            h.wfile.write(body)
            return
        h.connection.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 16384)
        h.send_response(200)
        h.send_header("Content-Type", "multipart/x-mixed-replace; boundary=frame")
        h.end_headers()
        try:
            while not self._stop.is_set():
                if self.stall.is_set():
                    self._stop.wait(0.05)
                    continue
                if not (self.frozen.is_set() and self._jpg):  # frozen: the last one again
                    n = self._count
                    self._count += 1
                    self.produced[n] = time.monotonic()
                    self._jpg = cv2.imencode(".jpg", stamp(n, self.size))[1].tobytes()
                jpg = self._jpg
                h.wfile.write(b"--frame\r\nContent-Type: image/jpeg\r\nContent-Length: "
                              + str(len(jpg)).encode() + b"\r\n\r\n" + jpg + b"\r\n")
                self._stop.wait(1.0 / self.fps)  # paced from the end of the send
        except OSError:  # the client went away
            pass

    def __enter__(self) -> MjpegCamera:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._server.shutdown()
        self._server.server_close()
