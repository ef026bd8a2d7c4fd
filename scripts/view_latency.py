#!/usr/bin/env python3
"""How interactive `pointray view` is: frames a second while the camera moves, and the time from
a camera change to its first frame and to its converged frame.

Usage: scripts/view_latency.py MODEL [--size 512] [--spp 64] [--drag-seconds 3] [--pointray BIN]

Starts the viewer on MODEL, talks to it as a page does (a WebSocket; this file's own minimal
client, Python's standard library only), then: (1) a drag: the camera turns 1° about the up
axis every 33 ms for DRAG seconds, frames counted as they arrive, with the preview scales the
viewer chose; (2) the drag stops: the time from the last change to the first frame of that view
and to the frame with all its samples (SIZE², SPP samples a pixel). Needs `cargo build --release`.
"""
import argparse, base64, json, math, os, socket, struct, subprocess, time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


class WebSocket:
    """A client for the viewer's socket: text and binary frames, unfragmented."""

    def __init__(self, host, port, path):
        self.sock = socket.create_connection((host, port))
        key = base64.b64encode(os.urandom(16)).decode()
        request = (f"GET {path} HTTP/1.1\r\nHost: {host}:{port}\r\nUpgrade: websocket\r\n"
                   f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n\r\n")
        self.sock.sendall(request.encode())
        head = b""
        while b"\r\n\r\n" not in head:
            head += self.sock.recv(1)
        if b" 101 " not in head.split(b"\r\n")[0]:
            raise SystemExit(f"no WebSocket: {head!r}")

    def _exact(self, n):
        data = b""
        while len(data) < n:
            chunk = self.sock.recv(n - len(data))
            if not chunk:
                raise EOFError
            data += chunk
        return data

    def recv(self):
        """The next message: str for text, bytes for binary."""
        while True:
            b0, b1 = self._exact(2)
            n = b1 & 0x7F
            if n == 126:
                n = struct.unpack(">H", self._exact(2))[0]
            elif n == 127:
                n = struct.unpack(">Q", self._exact(8))[0]
            payload = self._exact(n)
            opcode = b0 & 0x0F
            if opcode == 1:
                return payload.decode()
            if opcode == 2:
                return payload

    def send(self, text):
        data, mask = text.encode(), os.urandom(4)
        n = len(data)
        head = bytes([0x81]) + (bytes([0x80 | n]) if n < 126 else bytes([0x80 | 126]) + struct.pack(">H", n))
        self.sock.sendall(head + mask + bytes(b ^ mask[i % 4] for i, b in enumerate(data)))

    def frames_until(self, deadline):
        """Frame metadata (dicts) until `deadline` (time.monotonic()), each with its arrival time."""
        self.sock.settimeout(max(deadline - time.monotonic(), 0.001))
        out = []
        try:
            while time.monotonic() < deadline:
                m = self.recv()
                if isinstance(m, str):
                    meta = json.loads(m)
                    meta["at"] = time.monotonic()
                    out.append(meta)
                self.sock.settimeout(max(deadline - time.monotonic(), 0.001))
        except (socket.timeout, TimeoutError):
            pass
        self.sock.settimeout(None)
        return out


def turned(hello, degrees):
    eye, look, up = hello["eye"], hello["look_at"], hello["up"]
    off = [e - l for e, l in zip(eye, look)]
    a, (ux, uy, uz) = math.radians(degrees), up
    c, s = math.cos(a), math.sin(a)
    dot = off[0] * ux + off[1] * uy + off[2] * uz
    cross = [uy * off[2] - uz * off[1], uz * off[0] - ux * off[2], ux * off[1] - uy * off[0]]
    new = [off[k] * c + cross[k] * s + up[k] * dot * (1 - c) for k in range(3)]
    return {"eye": [look[k] + new[k] for k in range(3)], "look_at": look, "up": up}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("model")
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--drag-seconds", type=float, default=3.0)
    ap.add_argument("--pointray", default=os.path.join(ROOT, "target", "release", "pointray"))
    a = ap.parse_args()
    server = subprocess.Popen([a.pointray, "-q", "view", a.model, "--port", "0", "--no-open", "--width", str(a.size),
                               "--height", str(a.size), "--spp", str(a.spp)], stdout=subprocess.PIPE, text=True)
    try:
        address = server.stdout.readline().split("http://")[1].strip().rstrip("/")
        host, port = address.rsplit(":", 1)
        ws = WebSocket(host, int(port), "/ws")
        hello = json.loads(ws.recv())
        while True:  # the first view, converged
            m = ws.recv()
            if isinstance(m, str) and json.loads(m).get("samples") == a.spp:
                break
        # (1) The drag.
        start, frames, step = time.monotonic(), [], 0
        while time.monotonic() - start < a.drag_seconds:
            step += 1
            ws.send(json.dumps(turned(hello, step)))
            frames += ws.frames_until(time.monotonic() + 1 / 30)
        dragged = time.monotonic() - start
        shown = [f for f in frames if f.get("kind") == "frame"]
        scales = sorted({f["scale"] for f in shown})
        # (2) At rest: the last view's first frame and its converged one.
        step += 1
        sent = time.monotonic()
        ws.send(json.dumps(turned(hello, step)))
        first = done = None
        while done is None:  # the viewer counts views: this is the step-th
            m = ws.recv()
            if isinstance(m, str) and json.loads(m).get("generation") == step:
                meta = json.loads(m)
                if first is None:
                    first, first_scale = time.monotonic() - sent, meta["scale"]
                if meta["samples"] == a.spp:
                    done = time.monotonic() - sent
        print(f"{a.model}, {a.size}², up to {a.spp} samples a pixel:")
        print(f"  dragging: {len(shown) / dragged:.1f} frames a second ({len(shown)} in {dragged:.1f} s, "
              f"{step - 1} camera changes), preview scales {scales}")
        print(f"  at rest: first frame {first * 1000:.0f} ms after the change (scale {first_scale}), "
              f"converged after {done:.2f} s")
    finally:
        server.terminate()
        server.wait()


if __name__ == "__main__":
    main()
