#!/usr/bin/env python3
"""The operator's web server against hostile clients, with real sockets on loopback against the
real depthfuse-monitor process (no rig key: the case where the page's commands are unsigned).
Each case runs while a prober asks GET /api/status every 50 ms and the monitor's memory (VmRSS) is
sampled; each must keep /api/status answering (median within 100 ms) and the monitor's memory
within 48 MiB of where it started, and each stops by itself within seconds:

  frame_bomb     four clients open WebSockets that declare a 1,000 MB frame and send it, again
                 and again for 3 s: each is closed at once
  pages          ten WebSockets that stay connected: eight are served, the others refused (503)
  slow_requests  twelve requests whose headers or body never finish: closed after the timeout
  idle_flood     300 connections that send nothing: the oldest idle ones make room for new ones
  never_reader   while map deltas flow (depthfuse_web_map_feeder), a page that never reads is
                 dropped and a page that reads keeps getting the status ten times a second
  cross_origin   another origin's preflight, POST and WebSocket, and a Host that is not the
                 monitor's (DNS rebinding): refused; the same requests from the page's origin, or
                 from a client that is not a browser, are served
  browser        headless chromium: a page served from another port tries fetch, a form POST and a
                 WebSocket against the monitor: all refused; the monitor's own page works and shows
                 that commands are not authenticated; over https (a TLS proxy in this script) the
                 page's live view connects with wss://
Exit 0 pass, 1 fail. With --report-only the cases run and print their figures without failing,
to measure another build's monitor (--monitor PATH).

  test_web_hostile.py --bin build/bin [--monitor PATH] [--report-only] [--cases a,b]
"""
import argparse
import base64
import http.server
import json
import os
import re
import select
import shutil
import socket
import ssl
import statistics
import struct
import subprocess
import sys
import tempfile
import threading
import time

from webtest import Browser, Daemons, Failure, check, eventually, find_chromium, test_lcm_url

HOST = "127.0.0.1"
STATUS_MEDIAN_BOUND_S = 0.100
RSS_GROWTH_BOUND_MIB = 48


# ------------------------------------------------------------------ raw HTTP and WebSocket clients
def wait_for(pred, timeout_s):
    """pred()'s first true value within timeout_s, else None."""
    try:
        return eventually(pred, timeout_s, "")
    except Failure:
        return None


def read_head(sock, limit=65536):
    """The response's status code and headers (lower-case names), or (0, {}) when the server closed
    or said nothing in time. Reads no byte past the head: a WebSocket's first frames stay."""
    data = b""
    try:
        while not data.endswith(b"\r\n\r\n") and len(data) < limit:
            peek = sock.recv(4096, socket.MSG_PEEK)
            if not peek:
                break
            end = (data[-3:] + peek).find(b"\r\n\r\n")
            data += sock.recv(len(peek) if end < 0 else end + 4 - len(data[-3:]))
    except OSError:
        pass
    head = data.split(b"\r\n\r\n", 1)[0].decode("latin-1")
    lines = head.split("\r\n")
    m = re.match(r"HTTP/1\.[01] (\d{3})", lines[0]) if lines else None
    headers = {}
    for line in lines[1:]:
        if ":" in line:
            k, v = line.split(":", 1)
            headers[k.strip().lower()] = v.strip()
    return (int(m.group(1)) if m else 0), headers


def exchange(port, method, path, headers=None, body=b"", timeout=5.0):
    """One request on its own connection: (status code, headers, body)."""
    hdrs = {"Host": "%s:%d" % (HOST, port), "Connection": "close"}
    hdrs.update(headers or {})
    if body:
        hdrs["Content-Length"] = str(len(body))
    text = "%s %s HTTP/1.1\r\n" % (method, path) + "".join("%s: %s\r\n" % kv for kv in hdrs.items())
    with socket.create_connection((HOST, port), timeout=timeout) as s:
        s.sendall(text.encode() + b"\r\n" + body)
        code, head = read_head(s)
        data = b""
        while code:
            chunk = s.recv(65536)
            if not chunk:
                break
            data += chunk
    return code, head, data


def request(port, method, path, headers=None, body=b"", timeout=5.0):
    """One request on its own connection: (status code, headers)."""
    code, head, _ = exchange(port, method, path, headers, body, timeout)
    return code, head


def ws_connect(port, origin="same", host=None, rcvbuf=None, timeout=5.0):
    """A WebSocket handshake on /ws: (socket, status code). origin: "same" (the page's), None (no
    Origin header, as a client that is not a browser) or an origin."""
    s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    if rcvbuf:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
    s.settimeout(timeout)
    s.connect((HOST, port))
    host = host or "%s:%d" % (HOST, port)
    lines = ["GET /ws HTTP/1.1", "Host: " + host, "Upgrade: websocket", "Connection: Upgrade",
             "Sec-WebSocket-Key: " + base64.b64encode(os.urandom(16)).decode(),
             "Sec-WebSocket-Version: 13"]
    if origin == "same":
        lines.append("Origin: http://" + host)
    elif origin:
        lines.append("Origin: " + origin)
    s.sendall(("\r\n".join(lines) + "\r\n\r\n").encode())
    code, _ = read_head(s)
    return s, code


def recv_exact(sock, n):
    data = b""
    while len(data) < n:
        chunk = sock.recv(min(n - len(data), 1 << 20))
        if not chunk:
            raise EOFError
        data += chunk
    return data


class PageReader(threading.Thread):
    """A page that reads everything: the times of the status messages, the chunks' count."""

    def __init__(self, sock):
        super().__init__(daemon=True)
        self.sock = sock
        self.status_times = []
        self.chunks = 0
        self.closed = False
        self.stop = False
        sock.settimeout(1.0)

    def run(self):
        while not self.stop:
            try:
                b0, b1 = recv_exact(self.sock, 2)
                n = b1 & 0x7F
                if n == 126:
                    n = struct.unpack(">H", recv_exact(self.sock, 2))[0]
                elif n == 127:
                    n = struct.unpack(">Q", recv_exact(self.sock, 8))[0]
                payload = recv_exact(self.sock, n)
            except socket.timeout:
                continue
            except (EOFError, OSError):
                self.closed = True
                return
            opcode = b0 & 0x0F
            if opcode == 8:
                self.closed = True
                return
            if opcode == 2:
                self.chunks += 1
            elif opcode == 1 and payload.startswith(b'{"type": "status"'):
                self.status_times.append(time.monotonic())

    def max_gap_s(self):
        t = self.status_times
        return max((b - a for a, b in zip(t, t[1:])), default=float("inf"))


def closed_by_server(sock, timeout_s):
    """True when the server closes `sock` within timeout_s (what it sent is drained meanwhile)."""
    deadline = time.monotonic() + timeout_s
    sock.setblocking(False)
    while time.monotonic() < deadline:
        r, _, _ = select.select([sock], [], [], max(0.0, deadline - time.monotonic()))
        if not r:
            break
        try:
            if not sock.recv(1 << 16):
                return True
        except BlockingIOError:
            continue
        except OSError:
            return True
    return False


# ------------------------------------------------------------------ what each case is measured by
class StatusProbe(threading.Thread):
    """GET /api/status every period_s on a new connection; a failure counts as timeout_s."""

    def __init__(self, port, period_s=0.05, timeout_s=3.0):
        super().__init__(daemon=True)
        self.port, self.period_s, self.timeout_s = port, period_s, timeout_s
        self.latencies, self.failures = [], 0
        self.halt = threading.Event()

    def run(self):
        while not self.halt.is_set():
            t0 = time.monotonic()
            try:
                code, _ = request(self.port, "GET", "/api/status", timeout=self.timeout_s)
                ok = code == 200
            except OSError:
                ok = False
            self.latencies.append(time.monotonic() - t0 if ok else self.timeout_s)
            self.failures += 0 if ok else 1
            self.halt.wait(max(0.0, self.period_s - (time.monotonic() - t0)))

    def finish(self):
        self.halt.set()
        self.join()
        lat = sorted(self.latencies)
        return {"probes": len(lat), "failed": self.failures,
                "p50_ms": 1000 * statistics.median(lat) if lat else float("inf"),
                "max_ms": 1000 * lat[-1] if lat else float("inf")}


def rss_mib(pid):
    with open("/proc/%d/status" % pid) as f:
        return int(re.search(r"VmRSS:\s+(\d+)", f.read()).group(1)) / 1024.0


class RssSampler(threading.Thread):
    def __init__(self, pid):
        super().__init__(daemon=True)
        self.pid, self.peak, self.halt = pid, rss_mib(pid), threading.Event()

    def run(self):
        while not self.halt.wait(0.05):
            try:
                self.peak = max(self.peak, rss_mib(self.pid))
            except (OSError, AttributeError):
                return

    def finish(self):
        self.halt.set()
        self.join()
        return self.peak


class Monitor:
    def __init__(self, args, work, daemons):
        self.url = test_lcm_url()
        self.proc = daemons.start("monitor", [args.monitor, "--lcm", self.url, "--key-file", "",
                                              "--http", "%s:0" % HOST, "--rate", "10"])
        found = eventually(lambda: re.search(r"http://127\.0\.0\.1:(\d+)/", daemons.log("monitor")), 10,
                           "the monitor never said where its page is:\n" + daemons.log("monitor"))
        self.port = int(found.group(1))
        self.base = "http://%s:%d/" % (HOST, self.port)

    def counters(self):
        """The monitor's own heartbeat counters, from its status."""
        try:
            st = json.loads(exchange(self.port, "GET", "/api/status", timeout=3)[2])
        except (OSError, ValueError):
            return {}
        me = [d for d in st.get("daemons", []) if d["name"] == "monitor"]
        return me[0]["counters"] if me else {}

    def fds(self):
        return len(os.listdir("/proc/%d/fd" % self.proc.pid))


def run_case(name, monitor, fn, report_only):
    rss0 = rss_mib(monitor.proc.pid)
    probe, sampler = StatusProbe(monitor.port), RssSampler(monitor.proc.pid)
    probe.start()
    sampler.start()
    t0 = time.monotonic()
    try:
        extra = fn()
    finally:
        figures = probe.finish()
        peak = sampler.finish()
    alive = monitor.proc.poll() is None
    figures.update({"rss_start_mib": rss0, "rss_peak_mib": peak, "seconds": time.monotonic() - t0})
    print("%-13s RSS %.0f -> %.0f MiB; /api/status p50 %.1f ms, max %.0f ms (%d probes, %d failed); %s%s"
          % (name, rss0, peak, figures["p50_ms"], figures["max_ms"], figures["probes"], figures["failed"],
             extra.get("text", ""), "" if alive else "; THE MONITOR DIED"), flush=True)
    if report_only:
        return
    check(alive, "%s: the monitor died" % name)
    check(peak - rss0 <= RSS_GROWTH_BOUND_MIB, "%s: the monitor's memory grew by %.0f MiB (bound %d)"
          % (name, peak - rss0, RSS_GROWTH_BOUND_MIB))
    check(figures["p50_ms"] <= 1000 * STATUS_MEDIAN_BOUND_S and figures["failed"] == 0,
          "%s: /api/status answered slowly or not at all: %s" % (name, figures))
    for what, ok in extra.get("checks", []):
        check(ok, "%s: %s" % (name, what))


# ------------------------------------------------------------------ the cases
def case_frame_bomb(monitor, args):
    """Four clients, each declaring a 1,000 MB WebSocket frame and sending it, again and again for
    3 s (each bomb for up to 5 s)."""
    declared = 1000 << 20
    results = []

    def bomb():
        s, code = ws_connect(monitor.port)
        t0, sent = time.monotonic(), 0
        closed_s = None
        try:
            if code == 101:
                s.sendall(bytes([0x82, 0x80 | 127]) + struct.pack(">Q", declared) + b"\0\0\0\0")
                block = b"\0" * (1 << 20)
                while time.monotonic() - t0 < 5.0 and sent < declared:
                    s.sendall(block)
                    sent += len(block)
        except OSError:
            closed_s = time.monotonic() - t0
        if closed_s is None and closed_by_server(s, 1.0):
            closed_s = time.monotonic() - t0
        s.close()
        results.append((code, closed_s, sent))

    def bomber():
        t0 = time.monotonic()
        while time.monotonic() - t0 < 3.0:
            bomb()

    threads = [threading.Thread(target=bomber) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(30)
    closed = [c for _, c, _ in results if c is not None]
    text = "%d bombs, %d handshakes 101; %d closed by the monitor, the last after %.2f s; %.0f MB sent" % (
        len(results), sum(1 for c, _, _ in results if c == 101), len(closed), max(closed, default=float("nan")),
        sum(s for _, _, s in results) / 1e6)
    return {"text": text, "checks": [("every frame bomb closed within 2 s: %s" % results[:8],
                                      len(closed) == len(results) and max(closed) < 2.0)]}


def case_pages(monitor, args):
    """Ten WebSockets that read and stay for 3 s."""
    conns = [ws_connect(monitor.port) for _ in range(10)]
    readers = [PageReader(s) for s, code in conns if code == 101]
    for r in readers:
        r.start()
    time.sleep(3.0)
    for r in readers:
        r.stop = True
    for r in readers:
        r.join(5)
    for s, _ in conns:
        s.close()
    codes = [code for _, code in conns]
    stayed = sum(1 for r in readers if not r.closed and r.status_times)
    text = "answers %s; %d pages served throughout" % (
        ", ".join("%dx %d" % (codes.count(c), c) for c in sorted(set(codes))), stayed)
    return {"text": text, "checks": [
        ("eight pages served and the rest refused with 503: %s" % codes,
         codes.count(101) == 8 and codes.count(503) == 2),
        ("the served pages got the status throughout (%d of 8)" % stayed, stayed == 8)]}


def case_slow_requests(monitor, args):
    """Twelve requests sent a byte every half second: eight in their headers, four in their body."""
    host = "%s:%d" % (HOST, monitor.port)
    socks = []
    for i in range(12):
        s = socket.create_connection((HOST, monitor.port), timeout=5)
        if i < 8:
            s.sendall(("GET /api/status HTTP/1.1\r\nHost: %s\r\n" % host).encode())
        else:
            s.sendall(("POST /api/command HTTP/1.1\r\nHost: %s\r\nX-Depthfuse: 1\r\nContent-Type: "
                       "application/x-www-form-urlencoded\r\nContent-Length: 100\r\n\r\n" % host).encode())
        socks.append(s)
    t0 = time.monotonic()
    closed_at = [None] * len(socks)
    while time.monotonic() - t0 < 8.0 and None in closed_at:
        for i, s in enumerate(socks):
            if closed_at[i] is not None:
                continue
            try:
                s.send(b"X-Slow: 1\r\n" if i < 8 else b"a")
                r, _, _ = select.select([s], [], [], 0)
                if r and not s.recv(4096):
                    closed_at[i] = time.monotonic() - t0
            except OSError:
                closed_at[i] = time.monotonic() - t0
        time.sleep(0.5)
    for s in socks:
        s.close()
    done = [c for c in closed_at if c is not None]
    text = "%d of 12 closed by the monitor, the last after %.1f s" % (len(done), max(done, default=float("nan")))
    return {"text": text, "checks": [("every slow request closed within 6 s: %s" % closed_at,
                                      len(done) == 12 and max(done) < 6.0)]}


def case_idle_flood(monitor, args):
    """300 connections that send nothing, opened over 2 s and held until 3 s have passed."""
    fds0 = monitor.fds()
    socks, refused, fds_peak = [], 0, fds0
    t0 = time.monotonic()
    for i in range(300):
        try:
            socks.append(socket.create_connection((HOST, monitor.port), timeout=2))
        except OSError:
            refused += 1
        if i % 25 == 0:
            fds_peak = max(fds_peak, monitor.fds())
        time.sleep(max(0.0, t0 + 2.0 * (i + 1) / 300 - time.monotonic()))
    time.sleep(max(0.0, t0 + 3.0 - time.monotonic()))
    open_now = 0
    for s in socks:
        r, _, _ = select.select([s], [], [], 0)
        try:
            open_now += 0 if (r and not s.recv(16)) else 1
        except OSError:
            pass
        s.close()
    text = "%d connected (%d refused at connect), %d still open after 3 s; the monitor's descriptors %d -> %d" % (
        len(socks), refused, open_now, fds0, fds_peak)
    return {"text": text, "checks": [("the monitor held at most 64 more descriptors (%d -> %d)" % (fds0, fds_peak),
                                      fds_peak - fds0 <= 64)]}


def case_never_reader(monitor, args):
    """Map deltas at 2 MB/s; a page that never reads and one that does."""
    dropped0 = monitor.counters().get("web_pages_dropped", 0)
    feeder = subprocess.Popen([os.path.join(args.bin, "depthfuse_web_map_feeder"), "--lcm", monitor.url,
                               "--key-file", "", "--bytes-per-s", "2000000", "--seconds", "14"],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        good, code_good = ws_connect(monitor.port)
        reader = PageReader(good)
        reader.start()
        stuck, code_stuck = ws_connect(monitor.port, rcvbuf=4096)
        t0 = time.monotonic()
        dropped_s = None
        while time.monotonic() - t0 < 12.0:
            if monitor.counters().get("web_pages_dropped", 0) > dropped0:
                dropped_s = time.monotonic() - t0
                break
            time.sleep(0.25)
        # The reading page's updates go on after the drop too.
        time.sleep(1.0)
        t1 = time.monotonic()
        window = [t0] + [t for t in reader.status_times if t >= t0] + [t1]
        gap = max(b - a for a, b in zip(window, window[1:]))
        stuck_closed = closed_by_server(stuck, 3.0)
        reader.stop = True
        reader.join(5)
        good.close()
        stuck.close()
    finally:
        feeder.terminate()
        feeder.wait()
    text = ("the reading page: %d status messages in %.1f s, longest gap %.2f s, %d chunks; the stuck page %s" % (
        len(window) - 2, t1 - t0, gap, reader.chunks,
        "dropped after %.1f s" % dropped_s if dropped_s is not None else "never dropped"))
    return {"text": text, "checks": [
        ("both pages connected (%d, %d)" % (code_good, code_stuck), code_good == 101 and code_stuck == 101),
        ("the reading page got chunks", reader.chunks > 0),
        ("the reading page's status every 100 ms went on (longest gap %.2f s; bound 1 s)" % gap, gap < 1.0),
        ("the page that never reads was dropped within 10 s and its connection closed",
         dropped_s is not None and dropped_s < 10.0 and stuck_closed)]}


def case_cross_origin(monitor, args):
    port = monitor.port
    here = "http://%s:%d" % (HOST, port)
    other = "http://%s:%d" % (HOST, port + 1 if port < 65535 else port - 1)
    refused0 = monitor.counters().get("web_origin_refused", 0)
    form = {"Content-Type": "application/x-www-form-urlencoded"}
    checks, seen = [], {}

    def expect(what, code, headers, ok_codes):
        seen[what] = code
        checks.append(("%s answered %d %s" % (what, code, headers), code in ok_codes))

    code, h = request(port, "OPTIONS", "/api/command", {
        "Origin": other, "Access-Control-Request-Method": "POST",
        "Access-Control-Request-Headers": "x-depthfuse"})
    expect("a preflight from another origin", code, h, (403, 405))
    checks.append(("the preflight approved nothing: %s" % h,
                   not any(k.startswith("access-control-allow") for k in h)))
    for name, hdrs in (("a POST from another origin", dict(form, **{"Origin": other, "X-Depthfuse": "1"})),
                       ("a form POST from another origin", dict(form, Origin=other)),
                       ("a POST with Origin null", dict(form, **{"Origin": "null", "X-Depthfuse": "1"}))):
        code, h = request(port, "POST", "/api/command", hdrs, b"action=start")
        expect(name, code, h, (403,))
    s, code = ws_connect(port, origin=other)
    s.close()
    expect("a WebSocket from another origin", code, {}, (403,))
    # DNS rebinding: a name of the attacker's that resolves to 127.0.0.1; the browser then sends
    # that name as Host and as the page's origin.
    evil = "rebind.example:%d" % port
    code, h = request(port, "GET", "/api/status", {"Host": evil})
    expect("GET /api/status with Host %s" % evil, code, h, (403, 421))
    code, h = request(port, "POST", "/api/command",
                      dict(form, **{"Host": evil, "Origin": "http://" + evil, "X-Depthfuse": "1"}), b"action=start")
    expect("a POST with Host and Origin %s" % evil, code, h, (403, 421))
    s, code = ws_connect(port, origin="http://" + evil, host=evil)
    s.close()
    expect("a WebSocket with Host %s" % evil, code, {}, (403, 421))
    # What must still work: the page's own origin, localhost, and clients that are not browsers.
    code, h = request(port, "POST", "/api/command", dict(form, **{"Origin": here, "X-Depthfuse": "1"}),
                      b"action=checkpoint")
    expect("a POST from the page's origin", code, h, (202,))
    code, h = request(port, "POST", "/api/command",
                      dict(form, **{"Host": "localhost:%d" % port, "Origin": "http://localhost:%d" % port,
                                    "X-Depthfuse": "1"}), b"action=checkpoint")
    expect("a POST from http://localhost:%d" % port, code, h, (202,))
    code, h = request(port, "POST", "/api/command", dict(form, **{"X-Depthfuse": "1"}), b"action=checkpoint")
    expect("a POST without Origin (not a browser)", code, h, (202,))
    s, code = ws_connect(port)
    s.close()
    expect("a WebSocket from the page's origin", code, {}, (101,))
    # The counters reach the status with the monitor's next heartbeat.
    refused = wait_for(lambda: monitor.counters().get("web_origin_refused", 0) - refused0 >= 8 and
                       monitor.counters().get("web_origin_refused", 0) - refused0, 3)
    checks.append(("the monitor counted 8 refusals (web_origin_refused +%s)" % refused, refused == 8))
    text = "; ".join("%s: %d" % kv for kv in seen.items())
    return {"text": text, "checks": checks}


# ------------------------------------------------------------------ the browser
EVIL_PAGE = """<!DOCTYPE html><html><body><script>
window.result = {done: false};
(async () => {
  const m = %s, r = {};
  try {
    const x = await fetch(m + 'api/command', {method: 'POST', body: 'action=start',
        headers: {'X-Depthfuse': '1', 'Content-Type': 'application/x-www-form-urlencoded'}});
    r.post = 'answered ' + x.status;
  } catch (e) { r.post = 'refused'; }
  try {
    await fetch(m + 'api/command', {method: 'POST', mode: 'no-cors', body: 'action=start',
        headers: {'Content-Type': 'application/x-www-form-urlencoded'}});
    r.form = 'sent';
  } catch (e) { r.form = 'refused'; }
  try { r.status = 'read ' + (await (await fetch(m + 'api/status')).text()).length + ' bytes'; }
  catch (e) { r.status = 'refused'; }
  r.ws = await new Promise((resolve) => {
    const ws = new WebSocket(m.replace('http', 'ws') + 'ws');
    let got = 0;
    ws.onmessage = () => { got++; };
    ws.onopen = () => setTimeout(() => resolve('open, ' + got + ' messages'), 1500);
    ws.onclose = () => resolve(got ? 'closed after ' + got + ' messages' : 'refused');
  });
  window.result = Object.assign(r, {done: true});
})();
</script></body></html>"""


def serve_other_origin(page):
    class Handler(http.server.BaseHTTPRequestHandler):
        def do_GET(self):
            body = page.encode()
            self.send_response(200)
            self.send_header("Content-Type", "text/html")
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, *a):
            pass

    server = http.server.ThreadingHTTPServer((HOST, 0), Handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return server


class TlsProxy:
    """https://127.0.0.1:PORT/ in front of the monitor, as an operator's TLS proxy would be: TLS
    ends here and the bytes go on unchanged (Host and Origin as the browser sent them)."""

    def __init__(self, work, target_port):
        cert, key = os.path.join(work, "proxy.crt"), os.path.join(work, "proxy.key")
        subprocess.run(["openssl", "req", "-x509", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1",
                        "-nodes", "-days", "1", "-subj", "/CN=127.0.0.1", "-keyout", key, "-out", cert],
                       check=True, capture_output=True, timeout=30)
        self.ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
        self.ctx.load_cert_chain(cert, key)
        self.target = target_port
        self.listener = socket.create_server((HOST, 0))
        self.port = self.listener.getsockname()[1]
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self):
        while True:
            try:
                raw, _ = self.listener.accept()
            except OSError:
                return
            threading.Thread(target=self._serve, args=(raw,), daemon=True).start()

    def _serve(self, raw):
        try:
            tls = self.ctx.wrap_socket(raw, server_side=True)
            up = socket.create_connection((HOST, self.target))
        except (OSError, ssl.SSLError):
            raw.close()
            return

        def pump(src, dst):
            try:
                while True:
                    data = src.recv(65536)
                    if not data:
                        break
                    dst.sendall(data)
            except (OSError, ssl.SSLError):
                pass
            for s in (src, dst):
                try:
                    s.shutdown(socket.SHUT_RDWR)
                except OSError:
                    pass

        threading.Thread(target=pump, args=(up, tls), daemon=True).start()
        pump(tls, up)

    def close(self):
        self.listener.close()


def case_browser(monitor, args, work):
    chromium = find_chromium()
    if not chromium:
        return {"text": "skipped: chromium is not installed", "checks": []}
    refused0 = monitor.counters().get("web_origin_refused", 0)
    taken0 = monitor.counters().get("web_commands_taken", 0)
    other = serve_other_origin(EVIL_PAGE % json.dumps(monitor.base))
    proxy = TlsProxy(work, monitor.port)
    browser = Browser(chromium, os.path.join(work, "profile"), os.path.join(work, "chromium.log"),
                      extra_args=["--ignore-certificate-errors"])
    checks = []
    try:
        browser.open("http://%s:%d/" % (HOST, other.server_address[1]))
        result = wait_for(lambda: browser.evaluate("window.result && window.result.done && window.result"),
                          20) or {}
        for k in ("post", "status", "ws"):
            checks.append(("the other origin's %s: %s" % (k, result.get(k)), result.get(k) == "refused"))
        refused = wait_for(lambda: monitor.counters().get("web_origin_refused", 0) - refused0 >= 3 and
                           monitor.counters().get("web_origin_refused", 0) - refused0, 3) or 0
        # The preflight, the form POST and the WebSocket reach the monitor and are refused; the
        # status GET is answered, but the browser keeps it from the page (no CORS header).
        checks.append(("the monitor refused the other origin's preflight, form POST and WebSocket "
                       "(web_origin_refused +%d)" % refused, refused >= 3))

        browser.open(monitor.base)
        own = wait_for(lambda: browser.evaluate("!!(window.dfState && dfState.connected && dfState.status)"), 20)
        checks.append(("the monitor's own page connected", own))
        banner = browser.evaluate("(() => { const b = document.getElementById('no-key');"
                                  " return b && !b.hidden && b.getBoundingClientRect().height > 0"
                                  " ? b.textContent : ''; })()")
        checks.append(("the page says its commands are not authenticated: %r" % banner,
                       "not authenticated" in (banner or "")))
        browser.click("btn-pause")
        status = wait_for(lambda: browser.evaluate("dfState.commands.length && dfState.commands[0].status"), 10)
        checks.append(("the page's own command was taken (%s)" % status, status == 202))

        browser.open("https://%s:%d/" % (HOST, proxy.port))
        secure = wait_for(lambda: browser.evaluate("window.dfState && dfState.connected && dfState.status"
                                                   " && (dfState.wsUrl || 'connected')"), 20)
        checks.append(("over https the live view connects with wss:// (%s)" % secure,
                       str(secure).startswith("wss://")))
        browser.click("btn-pause")
        secure_status = wait_for(lambda: browser.evaluate("dfState.commands.length && dfState.commands[0].status"),
                                 10)
        checks.append(("the page's command over https was taken (%s)" % secure_status, secure_status == 202))
        # The monitor took the two commands of its own page, and none of the other origin's.
        wait_for(lambda: monitor.counters().get("web_commands_taken", 0) >= taken0 + 2, 3)
        time.sleep(0.3)
        taken = monitor.counters().get("web_commands_taken", 0) - taken0
        checks.append(("the monitor took exactly the own page's 2 commands (web_commands_taken +%d)" % taken,
                       taken == 2))
        text = "other origin: %s; own page: %s, banner %s, command %s; https: live view %s, command %s" % (
            result, "connected" if own else "NOT CONNECTED", "shown" if banner else "missing", status,
            secure or "NOT CONNECTED", secure_status)
    finally:
        browser.close()
        other.shutdown()
        proxy.close()
    return {"text": text, "checks": checks}


CASES = ["frame_bomb", "pages", "slow_requests", "idle_flood", "never_reader", "cross_origin", "browser"]


def run(args, work):
    daemons = Daemons(work)
    try:
        monitor = Monitor(args, work, daemons)
        eventually(lambda: monitor.counters(), 10, "the monitor's status never came")
        for name in args.cases:
            fn = globals()["case_" + name]
            run_case(name, monitor, (lambda: fn(monitor, args, work)) if name == "browser"
                     else (lambda: fn(monitor, args)), args.report_only)
        check(monitor.proc.poll() is None, "the monitor died")
        return 0
    finally:
        daemons.stop()


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--bin", required=True)
    ap.add_argument("--monitor", help="the monitor to test (default: BIN/depthfuse-monitor)")
    ap.add_argument("--report-only", action="store_true")
    ap.add_argument("--cases", default=",".join(CASES))
    args = ap.parse_args()
    args.monitor = args.monitor or os.path.join(args.bin, "depthfuse-monitor")
    args.cases = [c for c in args.cases.split(",") if c]
    for c in args.cases:
        if c not in CASES:
            ap.error("unknown case '%s' (%s)" % (c, ", ".join(CASES)))
    work = tempfile.mkdtemp(prefix="depthfuse-web-hostile-")
    try:
        code = run(args, work)
    except Failure as e:
        print("FAIL: %s\n(logs in %s)" % (e, work))
        path = os.path.join(work, "monitor.log")
        if os.path.exists(path):
            print("--- monitor.log (tail)\n%s" % open(path).read()[-2000:])
        return 1
    shutil.rmtree(work, ignore_errors=True)
    return code


if __name__ == "__main__":
    sys.exit(main())
