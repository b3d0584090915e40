#!/usr/bin/env python3
"""The operator's page end to end, in a real browser.

Starts depthfuse-capture (synthetic corner), depthfuse-fusion and depthfuse-monitor --http as real
processes on a per-test LCM port, all with a rig key of the test's, then:
  1. the HTTP server: bad paths, a command without the page's header, a 10 MB request and a client
     that never finishes its request are refused, and the status keeps coming (the LCM loop runs);
     a monitor without a key refuses to serve the page beyond loopback;
  2. the operator token: a command signed with the key (HMAC-SHA-512-256 by Python's hmac, the
     same as libsodium's and the page's) reaches the fusion daemon; unsigned, replayed, altered,
     wrongly keyed, stale and future ones are refused, and the monitor's status counts each kind;
  3. headless chromium (driven over the DevTools protocol on a pipe) loads the page, which asks
     for the key; with a wrong key, Start is refused (and counted), and the page asks again; with
     the right key, Start must start a scan, observed in the fusion daemon's own heartbeat on LCM
     (tools/lcm/watch.py); the cloud must then have points; a click on Pause must pause; a loop
     closure's correction published on LCM must move the path the page draws by its motion (a
     broken one and one of another scan are counted and ignored), and the closure line must show
     the fusion daemon's pose graph counters;
  4. a screenshot goes to <out>/operator-page.png; a click on Stop ends the scan, and its map
     stays on the page.
Exit 0 pass, 1 fail, 77 skipped (no chromium).

  test_operator_page.py --bin build/bin --python-dir build/python --watch tools/lcm/watch.py --out DIR
"""
import argparse
import hashlib
import hmac
import json
import os
import re
import shutil
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time

from webtest import (Browser, Daemons, Failure, check, eventually, find_chromium, http,
                     test_lcm_url)

HEARTBEAT_IDLE, HEARTBEAT_RUNNING, HEARTBEAT_PAUSED = 1, 2, 3


class Heartbeats:
    """The fusion daemon's heartbeats, read from LCM by tools/lcm/watch.py in the background."""

    def __init__(self, watch, python_dir, url):
        self.proc = subprocess.Popen(
            [sys.executable, watch, "--lcm", url, "--python-dir", python_dir, "--channel",
             "DEPTHFUSE_HEARTBEAT"], stdout=subprocess.PIPE, text=True)
        self.latest = {}
        self.lock = threading.Lock()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self):
        for line in self.proc.stdout:
            try:
                m = json.loads(line).get("message", {})
            except ValueError:
                continue
            with self.lock:
                self.latest[m.get("name")] = m

    def get(self, name):
        with self.lock:
            return self.latest.get(name)

    def stop(self):
        self.proc.terminate()
        self.proc.wait()


def sign(key, channel, body, utime):
    """The X-Depthfuse-Signature of a page command (apps/monitor/page_auth.hpp): "DFS1" | utime |
    HMAC-SHA-512-256(key, channel | NUL | body | "DFS1" | utime), in hex."""
    header = b"DFS1" + struct.pack(">q", utime)
    tag = hmac.new(key, channel.encode() + b"\0" + body + header, hashlib.sha512).digest()[:32]
    return (header + tag).hex()


def post_command(base, body, signature=None):
    headers = {"X-Depthfuse": "1"}
    if signature is not None:
        headers["X-Depthfuse-Signature"] = signature
    code, reply = http(base, "api/command", "POST", body, headers)
    return code, json.loads(reply or b"{}")


def monitor_counters(base):
    st = json.loads(http(base, "api/status")[1])
    me = [d for d in st.get("daemons", []) if d["name"] == "monitor"]
    return (me[0]["counters"], me[0]["last_error"]) if me else ({}, "")


def counted(base, expect, what, timeout_s=5):
    """Waits until the monitor's counters hold `expect`; the failure shows them as they are then."""
    try:
        eventually(lambda: all(monitor_counters(base)[0].get(k) == v for k, v in expect.items()),
                   timeout_s, what)
    except Failure as e:
        raise Failure("%s (expected %s): %s" % (e, expect, monitor_counters(base)[0]))


def status_utime(base):
    code, body = http(base, "api/status")
    check(code == 200, "GET /api/status answered %d" % code)
    return json.loads(body).get("utime", 0)


def test_server(base, port):
    code, body = http(base, "api/status")
    check(code == 200, "GET /api/status: %d" % code)
    st = json.loads(body)
    check(any(d["name"] == "fusion" for d in st.get("daemons", [])),
          "/api/status lists no fusion daemon: %s" % body[:300])
    for path in ("no-such-page", "..%2f..%2fetc/passwd", "api/status/x"):
        code, _ = http(base, path)
        check(code == 404, "GET /%s answered %d, not 404" % (path, code))
    code, body = http(base, "api/command", "POST", b"action=start")
    check(code == 403, "a command without X-Depthfuse answered %d, not 403" % code)

    # A client that sends half a request and waits, and one that announces 10 MB.
    slow = socket.create_connection(("127.0.0.1", port))
    slow.sendall(b"GET /api/status HTTP/1.1\r\nHost: x\r\n")
    big = socket.create_connection(("127.0.0.1", port))
    big.settimeout(10)
    big.sendall(b"POST /api/command HTTP/1.1\r\nHost: x\r\nX-Depthfuse: 1\r\n"
                b"Content-Type: application/x-www-form-urlencoded\r\nContent-Length: 10485760\r\n\r\n")
    try:
        big.sendall(b"a" * (1 << 20))
    except OSError:
        pass  # refused before the body: fine
    reply = big.recv(4096)
    check(b" 413 " in reply.split(b"\r\n")[0], "a 10 MB command was not refused with 413: %r" % reply[:100])
    big.close()
    before = status_utime(base)
    eventually(lambda: status_utime(base) > before, 5,
               "the status stopped changing with a slow client connected (LCM loop stalled?)")
    slow.close()


def test_signed_commands(base, key, heartbeats):
    """Commands over HTTP: only those signed with the rig key, fresh and new, are carried out."""
    code, body = http(base, "api/auth")
    auth = json.loads(body)
    check(code == 200 and auth.get("commands_need_key") is True,
          "GET /api/auth with a rig key: %d %s" % (code, body))
    channel = auth["channel"]
    now = lambda: int(time.time() * 1e6)
    body = b"action=checkpoint"
    expect = {"unsigned": 0, "bad_signature": 0, "stale": 0, "replayed": 0}

    def refused(what, reason, code_reply):
        code, reply = code_reply
        check(code == 401 and reply.get("refused") == reason,
              "%s: answered %d %s, not 401 refused %s" % (what, code, reply, reason))
        expect[reason] += 1

    refused("an unsigned command", "unsigned", post_command(base, body))
    refused("a signature that is not hex", "unsigned", post_command(base, body, "zz" * 44))
    good = sign(key, channel, body, now())
    code, reply = post_command(base, body, good)
    check(code == 202 and reply.get("command_id"), "a signed command: %d %s" % (code, reply))
    # It reached the fusion daemon, signed by the monitor: idle, it answers that no scan runs.
    eventually(lambda: heartbeats.get("fusion")["last_command_id"] == reply["command_id"] and
               "no scan" in heartbeats.get("fusion")["last_command_message"], 10,
               "the signed command never reached the fusion daemon: %s" % heartbeats.get("fusion"))
    refused("the same request again", "replayed", post_command(base, body, good))
    refused("another body under that signature", "bad_signature", post_command(base, b"action=stop", good))
    refused("a command signed with another key", "bad_signature",
            post_command(base, body, sign(os.urandom(32), channel, body, now())))
    refused("a command signed on another channel", "bad_signature",
            post_command(base, body, sign(key, "DEPTHFUSE_COMMAND", body, now())))
    refused("a command signed 10 s ago", "stale", post_command(base, body, sign(key, channel, body, now() - 10**7)))
    refused("a command signed 10 s ahead", "stale", post_command(base, body, sign(key, channel, body, now() + 10**7)))
    eventually(lambda: "page command refused (stale)" in monitor_counters(base)[1], 5,
               "the monitor's status does not name the last refusal: %s" % (monitor_counters(base),))
    code, reply = post_command(base, b"action=explode", sign(key, channel, b"action=explode", now()))
    check(code == 400 and "unknown action" in reply.get("error", ""),
          "a signed unknown action answered %d %s" % (code, reply))

    def counted():
        counters, last_error = monitor_counters(base)
        return all(counters.get("page_commands_refused_" + k) == v for k, v in expect.items()) and \
            counters.get("page_commands_verified") == 2 and \
            "page command refused" not in last_error
    eventually(counted, 5, "the monitor's status does not count the refusals %s and 2 verified, "
               "or still names a refusal after a command verified: %s" % (expect, monitor_counters(base)))
    return expect


def test_correction(browser, base, sender):
    """A loop closure's correction on LCM (as the fusion daemon sends it, signed with the rig key)
    moves the path the page draws, and the page notes it; a broken one and one of another scan are
    counted by the monitor and change nothing. The closure line shows the fusion daemon's pose graph
    counters. Called with the scan paused, so that the path holds still."""
    scan = browser.evaluate("dfState.pose && dfState.pose.scan_id")
    check(scan, "the page has no scan id: %s" % browser.evaluate("JSON.stringify(dfState.pose)"))
    path = lambda: browser.evaluate("Array.from(dfState.path)")

    def settled():
        a = path()
        time.sleep(1.0)
        return a if a and a == path() else None
    before = eventually(settled, 10, "the page's path kept changing while the scan was paused")

    def send(*extra):
        r = subprocess.run(sender + ["--scan-id"] + list(extra), capture_output=True, text=True, timeout=20)
        check(r.returncode == 0, "depthfuse_web_graph_sender failed: %s" % r.stderr)
    send(scan, "--spoil", "--dx", "1")
    send("another-scan", "--dx", "1")
    counted(base, {"graph_corrections_malformed": 1, "graph_corrections_other_scan": 1,
                   "graph_corrections_applied": 0},
            "the monitor did not count a broken correction and one of another scan as such")
    check(path()[:len(before)] == before and browser.evaluate("dfState.corrections.length") == 0,
          "a broken correction, or one of another scan, moved the page's path")
    # Every keyframe from sequence 0 on (so the whole path) turns 90 degrees about z, then moves.
    send(scan, "--first-sequence", "0", "--yaw-deg", "90", "--dx", "0.5", "--dy", "-0.25", "--dz", "1")
    eventually(lambda: browser.evaluate("dfState.corrections.length") == 1, 10,
               "the page got no note of the correction")
    after = path()
    # A delta after it may add the camera's (uncorrected) pose at the end: only the old ones count.
    check(len(after) >= len(before), "the path lost positions: %d, was %d" % (len(after), len(before)))
    for i in range(0, len(before), 3):
        x, y, z = before[i:i + 3]
        expect = (-y + 0.5, x - 0.25, z + 1)
        check(all(abs(a - e) < 1e-3 for a, e in zip(after[i:i + 3], expect)),
              "position %d of the path: %s, expected %s (was %s)" % (i // 3, after[i:i + 3], expect, before[i:i + 3]))
    note = browser.evaluate("(e => e.hidden ? '' : e.textContent)(document.getElementById('correction-note'))")
    check("correction 1 moved the path" in note, "the page's note of the correction: %r" % note)
    counted(base, {"graph_corrections_applied": 1}, "the monitor did not count the correction")

    # The closure line: the fusion daemon's counters, as the status the page has carries them.
    c = browser.evaluate("JSON.stringify(dfState.status.daemons.find(d => d.name === 'fusion').counters)")
    c = json.loads(c)
    real_line = browser.evaluate("document.getElementById('graph').textContent")
    last = ("%d correction" % c["graph_corrections"]) if c["graph_corrections"] else "no correction yet"
    for part in ("pose graph: %d keyframe" % c["keyframes"], "%d loop closure" % c["loop_closures"], last):
        check(part in real_line, "the closure line %r lacks %r (counters %s)" % (real_line, part, c))
    # The synthetic scan (with pose hints) builds no pose graph: the line as a scan with closures
    # makes it, drawn from counters in one go (the next status redraws it).
    line = browser.evaluate("showGraph({keyframes: 52, loop_closures: 30, graph_corrections: 3, "
                            "last_correction_mm: 4.5, loop_candidates: 40, loops_gated: 6, loops_rejected: 4}),"
                            " document.getElementById('graph').textContent")
    check(line == "pose graph: 52 keyframes, 30 loop closures, 3 corrections (last moved the map 4.5 mm)",
          "the closure line for a scan with closures: %r" % line)
    browser.evaluate("showGraph(dfState.status.daemons.find(d => d.name === 'fusion').counters)")
    # The frames line: what became of the frames received, from the same heartbeat.
    frames_line = browser.evaluate(
        "(d => (showFrames(d), [document.getElementById('frames').textContent, d]))"
        "(dfState.status.daemons.find(d => d.name === 'fusion'))")
    shown, d = frames_line
    expect = "frames: %d fused, %d tracked only (fusion behind), %d lost, %d dropped" % (
        d["frames_out"], d["counters"]["frames_fusion_shed"], d["counters"]["frames_lost_tracking"],
        d["frames_dropped"])
    check(shown == expect, "the frames line %r, expected %r" % (shown, expect))
    print("correction: the page's path (%d positions) moved as sent, noted; broken and foreign ones "
          "counted and ignored; %r" % (len(before) // 3, real_line))


def test_remote_needs_key(args, url, work):
    """A monitor without a rig key refuses to serve the page beyond loopback."""
    config = os.path.join(work, "remote.toml")
    with open(config, "w") as f:
        f.write("[monitor]\nhttp_allow_remote = true\n")
    r = subprocess.run([os.path.join(args.bin, "depthfuse-monitor"), "--lcm", url, "--config", config,
                        "--key-file", "", "--http", "0.0.0.0:0"],
                       capture_output=True, text=True, timeout=20)
    check(r.returncode != 0 and "needs the rig key" in r.stderr,
          "a monitor without a key served the page beyond loopback: exit %d, %s" % (r.returncode, r.stderr))


def run(args, work):
    chromium = find_chromium()
    if not chromium:
        print("SKIP: chromium is not installed (apt-get install chromium; tools/setup.sh)")
        return 77
    url = test_lcm_url()
    # The rig key, as the package makes it: 64 hex digits, not readable by every user.
    key = os.urandom(32)
    key_file = os.path.join(work, "rig.key")
    with open(os.open(key_file, os.O_WRONLY | os.O_CREAT, 0o600), "w") as f:
        f.write(key.hex() + "\n")
    keyed = ["--lcm", url, "--key-file", key_file]
    daemons = Daemons(work)
    heartbeats = Heartbeats(args.watch, args.python_dir, url)
    browser = None
    try:
        test_remote_needs_key(args, url, work)
        daemons.start("monitor", [os.path.join(args.bin, "depthfuse-monitor")] + keyed +
                      ["--http", "127.0.0.1:0"])
        found = eventually(lambda: re.search(r"http://127\.0\.0\.1:(\d+)/", daemons.log("monitor")), 10,
                           "the monitor never said where its page is:\n" + daemons.log("monitor"))
        port = int(found.group(1))
        base = "http://127.0.0.1:%d/" % port
        daemons.start("fusion", [os.path.join(args.bin, "depthfuse-fusion")] + keyed +
                      ["--scan-dir", os.path.join(work, "scans")])
        daemons.start("capture", [os.path.join(args.bin, "depthfuse-capture")] + keyed +
                      ["--source", "synthetic:corner", "--rate", "15", "--loop"])
        eventually(lambda: heartbeats.get("fusion"), 15, "no fusion heartbeat on LCM")
        eventually(lambda: any(d["name"] == "fusion" for d in
                               json.loads(http(base, "api/status")[1]).get("daemons", [])),
                   10, "the monitor's status never listed the fusion daemon")
        test_server(base, port)
        print("HTTP server: bad paths, missing header, 10 MB request, slow client, "
              "no remote page without a key: ok")
        refusals = test_signed_commands(base, key, heartbeats)
        print("signed commands: the right key's reaches fusion; refused and counted: %s" % refusals)

        browser = Browser(chromium, os.path.join(work, "profile"), os.path.join(work, "chromium.log"))
        browser.call("Target.setDiscoverTargets", {"discover": False}, session=False)
        browser.open(base)
        eventually(lambda: browser.evaluate(
            "!!(window.dfState && dfState.connected && dfState.status &&"
            " dfState.status.daemons.some(d => d.name === 'fusion'))"), 20,
            "the page never connected and showed the fusion daemon")
        check(heartbeats.get("fusion")["state"] != HEARTBEAT_RUNNING, "a scan runs before Start")
        check(browser.evaluate("dfState.points") == 0, "the page shows points before any scan")

        # The page asks for the key; a wrong one is refused by the monitor, counted, and asked again.
        eventually(lambda: browser.evaluate("dfState.needKey === true && "
                                            "!document.getElementById('key-form').hidden"), 10,
                   "the page did not ask for the rig key")
        browser.click("btn-start")
        eventually(lambda: browser.evaluate("dfState.commands.length") == 1, 10, "Start did nothing")
        check(browser.evaluate("dfState.commands[0].error") == "no key",
              "Start without a key: %s" % browser.evaluate("JSON.stringify(dfState.commands)"))

        def enter_key(hex_key):
            browser.evaluate("document.getElementById('rig-key').value = %s" % json.dumps(hex_key))
            browser.click("btn-key")
            eventually(lambda: browser.evaluate("document.getElementById('key-form').hidden"), 5,
                       "the page did not take the key")
        enter_key(os.urandom(32).hex())
        browser.click("btn-start")
        eventually(lambda: browser.evaluate("dfState.commands.length") == 2, 10, "Start did nothing")
        check(browser.evaluate("dfState.commands[1].status") == 401 and
              browser.evaluate("dfState.commands[1].reply.refused") == "bad_signature",
              "Start with a wrong key: %s" % browser.evaluate("JSON.stringify(dfState.commands[1])"))
        eventually(lambda: monitor_counters(base)[0].get("page_commands_refused_bad_signature") ==
                   refusals["bad_signature"] + 1, 5, "the wrong key's refusal was not counted")
        eventually(lambda: browser.evaluate("!document.getElementById('key-form').hidden"), 5,
                   "the page kept a key the monitor refused")
        check(heartbeats.get("fusion")["state"] != HEARTBEAT_RUNNING, "Start with a wrong key started a scan")
        print("page: Start without a key asks for it; with a wrong key refused (bad_signature), counted")
        enter_key(key.hex())
        browser.click("btn-start")
        eventually(lambda: heartbeats.get("fusion")["state"] == HEARTBEAT_RUNNING and
                   heartbeats.get("fusion")["scan_id"], 15,
                   "Start on the page did not start a scan (fusion heartbeat: %s)" % heartbeats.get("fusion"))
        print("Start: fusion runs scan %s" % heartbeats.get("fusion")["scan_id"])
        points = eventually(lambda: browser.evaluate("dfState.points") or 0, 30,
                            "the page's cloud got no points")
        eventually(lambda: browser.evaluate("dfState.trajectory") or 0, 10, "no trajectory drawn")
        time.sleep(2)  # a few more deltas, for the picture
        browser.click("btn-pause")
        eventually(lambda: heartbeats.get("fusion")["state"] == HEARTBEAT_PAUSED, 15,
                   "Pause on the page did not pause the scan")
        test_correction(browser, base, [os.path.join(args.bin, "depthfuse_web_graph_sender")] + keyed)
        points = browser.evaluate("dfState.points")
        chunks = browser.evaluate("dfState.chunks")
        coverage = browser.evaluate("dfState.coverage")
        print("page: %d points in %d chunks, coverage %.3f; Pause: fusion paused" % (points, chunks, coverage))
        os.makedirs(args.out, exist_ok=True)
        shot = os.path.join(args.out, "operator-page.png")
        browser.screenshot(shot)
        check(os.path.getsize(shot) > 10000, "the screenshot is nearly empty")
        print("screenshot: %s" % shot)
        browser.click("btn-stop")
        eventually(lambda: heartbeats.get("fusion")["state"] == HEARTBEAT_IDLE, 30,
                   "Stop on the page did not end the scan")
        time.sleep(1.5)  # a few idle deltas
        check(browser.evaluate("dfState.points") >= points,
              "the stopped scan's map left the page (%s points)" % browser.evaluate("dfState.points"))
        print("Stop: fusion idle, the map stays on the page")
        return 0
    finally:
        if browser:
            browser.close()
        daemons.stop()
        heartbeats.stop()


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--bin", required=True)
    ap.add_argument("--python-dir", required=True)
    ap.add_argument("--watch", required=True)
    ap.add_argument("--out", required=True)
    args = ap.parse_args()
    work = tempfile.mkdtemp(prefix="depthfuse-web-")
    try:
        code = run(args, work)
    except Failure as e:
        print("FAIL: %s\n(logs in %s)" % (e, work))
        for name in ("monitor", "fusion", "capture"):
            path = os.path.join(work, name + ".log")
            if os.path.exists(path):
                print("--- %s.log (tail)\n%s" % (name, open(path).read()[-2000:]))
        return 1
    shutil.rmtree(work, ignore_errors=True)
    return code


if __name__ == "__main__":
    sys.exit(main())
