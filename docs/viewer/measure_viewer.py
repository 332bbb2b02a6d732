#!/usr/bin/env python3
"""Measure the viewer page in headless Chromium in real time (the browser tests use virtual time,
whose clock does not advance with work). Standard library only: a minimal DevTools-protocol
client over a websocket to 127.0.0.1.

    python3 docs/viewer/measure_viewer.py FOLDER/index.html [WIDTH HEIGHT]

Prints: time to the first drawn frame (the reduced level) and to a complete view at fit, the
redraw time while the light moves (30 frames, each waited for with readPixels), and the time to
a complete 1:1 view after jumping to the image centre (tiles of level 0 loaded on demand).
"""
import base64, json, os, socket, subprocess, sys, tempfile, time, urllib.request

def ws_connect(url):
    host_port, path = url[len("ws://"):].split("/", 1)
    host, port = host_port.split(":")
    s = socket.create_connection((host, int(port)), timeout=120)
    key = base64.b64encode(os.urandom(16)).decode()
    s.sendall((f"GET /{path} HTTP/1.1\r\nHost: {host_port}\r\nUpgrade: websocket\r\n"
               f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n\r\n").encode())
    buf = b""
    while b"\r\n\r\n" not in buf:
        buf += s.recv(4096)
    assert b" 101 " in buf.split(b"\r\n")[0], buf
    return s

def ws_send(s, text):
    data = text.encode()
    mask = os.urandom(4)
    n = len(data)
    head = bytes([0x81]) + (bytes([0x80 | n]) if n < 126 else bytes([0x80 | 126]) + n.to_bytes(2, "big")
                            if n < 65536 else bytes([0x80 | 127]) + n.to_bytes(8, "big"))
    s.sendall(head + mask + bytes(b ^ mask[i % 4] for i, b in enumerate(data)))

def recv_exact(s, n):
    out = b""
    while len(out) < n:
        chunk = s.recv(n - len(out))
        if not chunk:
            raise EOFError
        out += chunk
    return out

def ws_recv(s):
    msg = b""
    while True:
        b0, b1 = recv_exact(s, 2)
        n = b1 & 0x7F
        if n == 126:
            n = int.from_bytes(recv_exact(s, 2), "big")
        elif n == 127:
            n = int.from_bytes(recv_exact(s, 8), "big")
        msg += recv_exact(s, n)
        if b0 & 0x80:
            return msg.decode()

class Page:
    def __init__(self, ws):
        self.ws, self.id = ws, 0
    def call(self, method, **params):
        self.id += 1
        ws_send(self.ws, json.dumps({"id": self.id, "method": method, "params": params}))
        while True:
            m = json.loads(ws_recv(self.ws))
            if m.get("id") == self.id:
                return m.get("result")
    def eval(self, expr):
        r = self.call("Runtime.evaluate", expression=expr, returnByValue=True, awaitPromise=True)
        return r["result"].get("value")

def wait_ready(page, timeout=300):
    t = time.time()
    while time.time() - t < timeout:
        st = page.eval("document.getElementById('ps-state') && document.getElementById('ps-state').textContent")
        if st:
            st = json.loads(st)
            if st.get("ready"):
                return st, time.time() - t
        time.sleep(0.05)
    raise TimeoutError("page not ready")

def main():
    index = os.path.abspath(sys.argv[1])
    w, h = (int(sys.argv[2]), int(sys.argv[3])) if len(sys.argv) > 3 else (1600, 1000)
    profile = tempfile.mkdtemp()
    proc = subprocess.Popen(["chromium", "--headless", "--no-sandbox", "--disable-gpu", "--enable-unsafe-swiftshader",
                             "--disable-quic", "--no-first-run", "--disable-background-networking",
                             "--disable-component-update", "--disable-sync", f"--user-data-dir={profile}",
                             "--force-device-scale-factor=1", f"--window-size={w},{h}",
                             "--remote-debugging-address=127.0.0.1", "--remote-debugging-port=0", "about:blank"],
                            stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True)
    try:
        for line in proc.stderr:
            if "DevTools listening on" in line:
                browser_ws = line.strip().split(" on ")[1]
                break
        port = browser_ws.split(":")[2].split("/")[0]
        targets = json.load(urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=10))
        page = Page(ws_connect([t for t in targets if t["type"] == "page"][0]["webSocketDebuggerUrl"]))
        page.call("Page.enable")
        t = time.time()
        page.call("Page.navigate", url="file://" + index + "#layer=relight")
        st, wall = wait_ready(page)
        print(f"canvas {st['canvas']}, level {st['level']}: first frame {st['first_draw_ms']:.0f} ms, "
              f"complete {st['ready_ms']:.0f} ms after the script started (wall {wall:.2f} s)")
        b = page.eval("PSV.bench(30)")
        print(f"light drag at fit: {b['frames']} redraws, mean {b['mean_ms']:.1f} ms, median {b['median_ms']:.1f} ms, "
              f"p95 {b['p95_ms']:.1f} ms, max {b['max_ms']:.1f} ms (level {b['level']})")
        m = page.eval("JSON.parse(document.getElementById('ps-manifest').textContent)")
        t0 = page.eval("performance.now()")
        page.eval(f"PSV.setView(1, {m['width'] / 2}, {m['height'] / 2})")
        st, wall = wait_ready(page)
        print(f"jump to 1:1 at the centre: complete after {st['ready_at_ms'] - t0:.0f} ms "
              f"({st['tiles_cached']} tiles cached)")
        b = page.eval("PSV.bench(30)")
        print(f"light drag at 1:1: mean {b['mean_ms']:.1f} ms, p95 {b['p95_ms']:.1f} ms, max {b['max_ms']:.1f} ms")
        mem = page.eval("performance.memory ? performance.memory.usedJSHeapSize : null")
        if mem:
            print(f"JS heap in use: {mem / 1e6:.0f} MB")
    finally:
        proc.kill()
        proc.wait()

if __name__ == "__main__":
    main()
