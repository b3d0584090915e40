"""What the web tests share: checks that fail with a message, waiting for a condition, the
daemons as child processes with their logs, plain HTTP requests, and headless chromium driven over
the DevTools protocol."""
import base64
import json
import os
import shutil
import socket
import subprocess
import time
import urllib.error
import urllib.request


def test_lcm_url():
    """A udpm URL for this test process alone, as tests/lcm/lcm_test_util.hpp chooses one: a port
    from the process id in 10000..31999, below the kernel's ephemeral range (where a sending
    socket's automatic bind can hold a port the receivers then cannot bind), moved on past a port
    something else holds."""
    def bindable(port):
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            s.bind(("", port))
            return True
        except OSError:
            return False
        finally:
            s.close()
    ports = [10000 + (os.getpid() + i) % 22000 for i in range(64)]
    port = next((p for p in ports if bindable(p)), ports[0])
    return "udpm://239.255.76.67:%d?ttl=0&recv_buf_size=4194304" % port


class Failure(Exception):
    pass


def check(cond, what):
    if not cond:
        raise Failure(what)


def eventually(pred, timeout_s, what, period_s=0.25):
    deadline = time.monotonic() + timeout_s
    while True:
        value = pred()
        if value:
            return value
        if time.monotonic() > deadline:
            raise Failure("within %.0f s: %s" % (timeout_s, what))
        time.sleep(period_s)


class Daemons:
    """Child processes with their output in log files; terminated (SIGTERM) at the end."""

    def __init__(self, work):
        self.work = work
        self.procs = []

    def start(self, name, argv):
        log = open(os.path.join(self.work, name + ".log"), "w")
        p = subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT)
        self.procs.append((name, p, log))
        return p

    def log(self, name):
        with open(os.path.join(self.work, name + ".log")) as f:
            return f.read()

    def stop(self):
        for _, p, _ in reversed(self.procs):
            if p.poll() is None:
                p.terminate()
        for name, p, log in self.procs:
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
            log.close()


class Browser:
    """Headless chromium, driven over the DevTools protocol on a pipe (--remote-debugging-pipe:
    JSON messages separated by NUL on file descriptors 3 and 4), so no WebSocket client is needed."""

    def __init__(self, chromium, profile, log_path, extra_args=()):
        to_browser_r, self.to_browser = os.pipe()
        self.from_browser, from_browser_w = os.pipe()

        def wire():
            os.dup2(to_browser_r, 3)
            os.dup2(from_browser_w, 4)

        self.log = open(log_path, "w")
        self.proc = subprocess.Popen(
            [chromium, "--headless", "--no-sandbox", "--remote-debugging-pipe",
             "--disable-background-networking", "--use-gl=angle", "--use-angle=swiftshader",
             "--enable-unsafe-swiftshader", "--window-size=1280,800", "--no-first-run",
             "--user-data-dir=" + profile]
            + list(extra_args) + ["about:blank"],
            stdout=self.log, stderr=subprocess.STDOUT, pass_fds=(3, 4), preexec_fn=wire)
        os.close(to_browser_r)
        os.close(from_browser_w)
        self.next_id = 0
        self.buffer = b""
        self.session = None

    def call(self, method, params=None, session=True, timeout_s=30):
        self.next_id += 1
        msg = {"id": self.next_id, "method": method, "params": params or {}}
        if session and self.session:
            msg["sessionId"] = self.session
        os.write(self.to_browser, json.dumps(msg).encode() + b"\0")
        deadline = time.monotonic() + timeout_s
        while True:
            while b"\0" in self.buffer:
                raw, self.buffer = self.buffer.split(b"\0", 1)
                reply = json.loads(raw)
                if reply.get("id") == self.next_id:
                    if "error" in reply:
                        raise Failure("%s: %s" % (method, reply["error"]))
                    return reply.get("result", {})
            if time.monotonic() > deadline or self.proc.poll() is not None:
                raise Failure("chromium did not answer %s" % method)
            chunk = os.read(self.from_browser, 1 << 20)
            if not chunk:
                raise Failure("chromium closed the DevTools pipe")
            self.buffer += chunk

    def open(self, url):
        target = self.call("Target.createTarget", {"url": url}, session=False)["targetId"]
        self.session = self.call("Target.attachToTarget", {"targetId": target, "flatten": True},
                                 session=False)["sessionId"]

    def evaluate(self, expression):
        r = self.call("Runtime.evaluate", {"expression": expression, "returnByValue": True})
        return r.get("result", {}).get("value")

    def click(self, element_id):
        rect = self.evaluate("(() => { const r = document.getElementById(%s).getBoundingClientRect();"
                             " return [r.x + r.width / 2, r.y + r.height / 2]; })()" % json.dumps(element_id))
        check(rect, "no element #%s on the page" % element_id)
        for kind in ("mousePressed", "mouseReleased"):
            self.call("Input.dispatchMouseEvent", {"type": kind, "x": rect[0], "y": rect[1],
                                                   "button": "left", "clickCount": 1})

    def screenshot(self, path):
        data = self.call("Page.captureScreenshot", {"format": "png"})["data"]
        with open(path, "wb") as f:
            f.write(base64.b64decode(data))

    def close(self):
        try:
            self.call("Browser.close", session=False, timeout_s=5)
        except Failure:
            pass
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        self.log.close()


def http(base, path, method="GET", body=None, headers=None):
    req = urllib.request.Request(base + path, data=body, method=method, headers=headers or {})
    try:
        with urllib.request.urlopen(req, timeout=10) as r:
            return r.status, r.read()
    except urllib.error.HTTPError as e:
        return e.code, e.read()


def find_chromium():
    return shutil.which("chromium") or shutil.which("chromium-browser")
