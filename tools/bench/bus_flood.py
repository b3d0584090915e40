#!/usr/bin/env python3
"""Bus flood benchmark (issue 22): fuzzed udpm packets against a running monitor and fusion daemon.

A capture daemon publishes the synthetic room (or --source) at 30 Hz, looping, to a fusion daemon and a monitor on
a private loopback port. The script records the valid datagrams on the bus for a few seconds (LC02
short messages and LC03 fragments of our messages: depth and colour frames, poses, heartbeats,
status), measures the fused rate for --quiet-s seconds, then sends --packets mutations of them (bit
flips, bytes set to 0x00/0xff, truncations and extensions, LC03 header fields set to extreme
values, fragments out of their message, channel names garbled) at --rate packets per second, and
measures the fused rate during the flood. At the end both daemons must still be alive.

  tools/bench/bus_flood.py [--bin DIR] [--packets N] [--rate PPS] [--quiet-s S] [--port P]
                           [--sender-nice N] [--key-file FILE] [--source SPEC] [--sham]

On the appliance the attacker's CPU is somebody else's; on one small machine the sender (Python)
competes with the daemons for the same cores. It therefore runs as its own process at nice
--sender-nice (19 by default; 0 makes it an equal), and the script prints each daemon's CPU during
the flood, which is the cost the flood really puts on the rig. With --key-file the daemons verify a
rig key, so every flood packet is dropped after reassembly, before any decode.

Rates come from the daemons' own counters, not from listening to the bus: the fusion daemon's
frames fused and the capture's frames published (`frames_out` in `depthfuse status --json`), over
each daemon's own uptime between two status replies taken at a window's ends. A listener of ours
would receive every flood packet too (in Python, 0.17 cores at 10^4 packets/s), a cost the rig
does not bear. The daemons' refusal counters come from the same status after the flood; the
monitor's own status messages are listened for only after it. A benchmark, not a test: it prints
figures.
"""
import argparse
import json
import os
import random
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time

GROUP = "239.255.76.67"
SHORT_MAGIC = 0x4C433032  # "LC02"
FRAGMENT_MAGIC = 0x4C433033  # "LC03"


def parse_args():
    here = os.path.dirname(os.path.abspath(__file__))
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--bin", default=os.path.join(here, "..", "..", "build", "bin"))
    p.add_argument("--packets", type=int, default=1_000_000)
    p.add_argument("--rate", type=float, default=10_000.0, help="packets per second")
    p.add_argument("--quiet-s", type=float, default=30.0, help="measurement without the flood")
    p.add_argument("--port", type=int, default=7697)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--sender-nice", type=int, default=19,
                   help="nice value of the flood's sender process (0: an equal of the daemons)")
    p.add_argument("--key-file", default="", help="a rig key for every daemon (default: none)")
    p.add_argument("--source", default="synthetic:room?frames=900",
                   help="the capture's source (looped at 30 Hz)")
    p.add_argument("--sham", action="store_true",
                   help="send nothing for as long as the flood would last: the control run, whose "
                        "rates over the same stretch of the capture's loop the flood's are compared with")
    return p.parse_args()


def status(bin_dir, url, key_file):
    """The fusion daemon's and the monitor's entries of one status, by name."""
    run = subprocess.run([os.path.join(bin_dir, "depthfuse"), "status", "--json", "--lcm", url,
                          "--key-file", key_file, "--timeout", "5"], capture_output=True, timeout=30)
    # Forged heartbeats may name daemons with any bytes: the monitor lists them too.
    problem = "no status line"
    for line in run.stdout.decode("utf-8", errors="replace").splitlines():
        try:
            return {d["name"]: d for d in json.loads(line, strict=False)["daemons"]}
        except (ValueError, KeyError) as e:
            problem = "%s in %r" % (e, line[:200])
    print("depthfuse status (exit %d): %s; %s" % (run.returncode, problem,
                                                  run.stderr.decode(errors="replace")[:300]),
          file=sys.stderr)
    return {}


def record(port, seconds):
    """Valid datagrams seen on the bus for `seconds`."""
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM, socket.IPPROTO_UDP)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    if hasattr(socket, "SO_REUSEPORT"):
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
    s.bind(("", port))
    s.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP,
                 struct.pack("4s4s", socket.inet_aton(GROUP), socket.inet_aton("0.0.0.0")))
    s.settimeout(0.5)
    seen = []
    end = time.time() + seconds
    while time.time() < end:
        try:
            d, _ = s.recvfrom(70000)
        except socket.timeout:
            continue
        if len(d) >= 8 and struct.unpack(">I", d[:4])[0] in (SHORT_MAGIC, FRAGMENT_MAGIC):
            seen.append(d)
    s.close()
    return seen


def cpu_seconds(pid):
    """User plus system CPU of a process so far, from /proc."""
    with open("/proc/%d/stat" % pid) as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


class StatusListener:
    """Listens for the monitor's status messages on the bus (LC02, or the first LC03 fragment of
    DEPTHFUSE_STATUS): that the monitor is still heard after the flood."""

    def __init__(self, port):
        self.status_sizes = []  # (LC02 or LC03 fragment 0, bytes)
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM, socket.IPPROTO_UDP)
        self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        if hasattr(socket, "SO_REUSEPORT"):
            self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
        self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
        self._sock.bind(("", port))
        self._sock.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP, struct.pack(
            "4s4s", socket.inet_aton(GROUP), socket.inet_aton("0.0.0.0")))
        self._sock.settimeout(0.5)
        self._stop = False
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self):
        short = struct.pack(">I", SHORT_MAGIC)
        fragment = struct.pack(">I", FRAGMENT_MAGIC)
        while not self._stop:
            try:
                d = self._sock.recv(70000)
            except socket.timeout:
                continue
            if d[:4] == short and d[8:25] == b"DEPTHFUSE_STATUS\0":
                self.status_sizes.append(("LC02", len(d)))
            elif d[:4] == fragment and d[20:37] == b"DEPTHFUSE_STATUS\0":
                self.status_sizes.append(("LC03", struct.unpack(">I", d[8:12])[0]))

    def stop(self):
        self._stop = True
        self._thread.join()
        self._sock.close()


class Window:
    """The fused and published rates and every process's CPU between start() and stop(), from the
    daemons' counters over their own uptime."""

    def __init__(self, a, url, procs):
        self.a, self.url, self.procs = a, url, procs

    def _snapshot(self):
        st = status(self.a.bin, self.url, self.a.key_file)
        cpu = {n: cpu_seconds(p.pid) for n, p in self.procs.items() if p.poll() is None}
        cpu["bench"] = cpu_seconds(os.getpid())
        return st, cpu, time.time()

    def start(self):
        self._begin = self._snapshot()

    def stop(self):
        (s0, c0, t0), (s1, c1, t1) = self._begin, self._snapshot()

        def rate(name):
            if name not in s0 or name not in s1:
                return float("nan")
            dt = s1[name]["uptime_s"] - s0[name]["uptime_s"]
            return (s1[name]["frames_out"] - s0[name]["frames_out"]) / dt if dt > 0 else float("nan")

        self.fused, self.published = rate("fusion"), rate("capture")
        self.cpu = {n: (c1[n] - c0[n]) / (t1 - t0) for n in c1 if n in c0}
        return self

    def describe(self):
        return "%.1f frames/s fused, %.1f published by the capture (%.0f %%); CPU (cores): %s" % (
            self.fused, self.published, 100.0 * self.fused / self.published if self.published else 0,
            ", ".join("%s %.2f" % kv for kv in sorted(self.cpu.items())))


def mutate(rng, d):
    """One fuzzed datagram from a valid one. Nine in ten keep at most their first 1400 bytes (the
    headers, the channel and the start of the message): loopback carries 64 KB fragments at only
    about a thousand a second on a small machine, and the bounds checks are in the first bytes."""
    b = bytearray(d if rng.random() < 0.1 else d[:1400])
    kind = rng.randrange(8)
    if kind == 0:  # bit flips
        for _ in range(rng.randint(1, 8)):
            i = rng.randrange(len(b))
            b[i] ^= 1 << rng.randrange(8)
    elif kind == 1:  # bytes set to extremes
        for _ in range(rng.randint(1, 4)):
            b[rng.randrange(len(b))] = rng.choice((0x00, 0xFF, 0x7F, 0x80))
    elif kind == 2:  # truncated
        b = b[:rng.randrange(len(b))]
    elif kind == 3:  # extended with noise, within the largest UDP datagram
        b += bytes(rng.getrandbits(8) for _ in range(rng.randint(1, 64)))
        del b[65507:]
    elif kind == 4 and len(b) >= 20 and struct.unpack(">I", b[:4])[0] == FRAGMENT_MAGIC:
        # An LC03 header field set to an extreme: message size, fragment offset, number, count.
        field = rng.choice(((8, ">I"), (12, ">I"), (16, ">H"), (18, ">H")))
        extreme = rng.choice((0, 1, 0xFFFF, 0xFFFFFF00, 0xFFFFFFFF, 0x7FFFFFFF))
        extreme &= 0xFFFF if field[1] == ">H" else 0xFFFFFFFF
        struct.pack_into(field[1], b, field[0], extreme)
    elif kind == 5 and len(b) >= 8:  # another sequence number: fragments of no message
        struct.pack_into(">I", b, 4, rng.getrandbits(32))
    elif kind == 6:  # the channel name garbled (its bytes after the header)
        start = 20 if struct.unpack(">I", b[:4])[0] == FRAGMENT_MAGIC else 8
        for i in range(start, min(len(b), start + 16)):
            if rng.random() < 0.3:
                b[i] = rng.getrandbits(8)
    else:  # random bytes from some offset on
        i = rng.randrange(len(b))
        b[i:] = bytes(rng.getrandbits(8) for _ in range(min(len(b) - i, 64))) + b[i + 64:]
    return bytes(b)


def flood(port, seeds, packets, rate, rng, nice):
    """Sends the mutations from a child process at the given nice value; returns (sent, send
    errors, seconds, the sender's CPU seconds)."""
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM, socket.IPPROTO_UDP)
    s.bind(("", 0))
    s.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 0)
    s.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_LOOP, 1)
    read_end, write_end = os.pipe()
    child = os.fork()
    if child == 0:
        os.close(read_end)
        os.nice(nice)
        sent = errors = 0
        start = time.time()
        # A pool of mutations made up front, so that Python's speed does not set the rate.
        pool = [mutate(rng, rng.choice(seeds)) for _ in range(min(packets, 20000))]
        while sent < packets:
            for d in pool[:min(len(pool), packets - sent)]:
                try:
                    s.sendto(d, (GROUP, port))
                except OSError:
                    errors += 1
                sent += 1
                if sent % 1000 == 0:
                    ahead = sent / rate - (time.time() - start)
                    if ahead > 0:
                        time.sleep(ahead)
            pool = [mutate(rng, rng.choice(seeds)) for _ in range(len(pool))]
        os.write(write_end, json.dumps([sent, errors, time.time() - start]).encode())
        os._exit(0)
    os.close(write_end)
    s.close()
    with os.fdopen(read_end) as f:
        result = f.read()
    _, _, usage = os.wait4(child, 0)
    sent = tuple(json.loads(result)) if result else (0, 0, 1e-9)
    # The sender's CPU includes the kernel's loopback delivery to every receiver's socket, done in
    # its send calls: on the appliance that part is the network interrupt's, on the rig's cores.
    return sent + (usage.ru_utime + usage.ru_stime,)


def main():
    a = parse_args()
    url = "udpm://%s:%d?ttl=0&recv_buf_size=4194304" % (GROUP, a.port)
    work = tempfile.mkdtemp(prefix="depthfuse-flood.")
    rng = random.Random(a.seed)
    procs = {}

    def start(name, argv):
        log = open(os.path.join(work, name + ".log"), "w")
        procs[name] = subprocess.Popen([os.path.join(a.bin, argv[0])] + argv[1:] +
                                       ["--lcm", url, "--key-file", a.key_file],
                                       stdout=log, stderr=subprocess.STDOUT)

    try:
        start("monitor", ["depthfuse-monitor"])
        start("fusion", ["depthfuse-fusion", "--scan-dir", os.path.join(work, "scans"),
                         "--autostart", "flood"])
        time.sleep(1)
        start("capture", ["depthfuse-capture", "--source", a.source, "--rate", "30", "--loop"])
        time.sleep(5)
        seeds = record(a.port, 5)
        kinds = {}
        for d in seeds:
            k = "LC03" if struct.unpack(">I", d[:4])[0] == FRAGMENT_MAGIC else "LC02"
            kinds[k] = kinds.get(k, 0) + 1
        if not seeds:
            sys.exit("no datagrams on the bus: is the multicast route there (tools/lcm/route)?")
        print("# %s, %s" % (os.path.abspath(a.bin), url))
        print("recorded %d valid datagrams (%s)" % (len(seeds), ", ".join(
            "%d %s" % (n, k) for k, n in sorted(kinds.items()))))
        quiet = Window(a, url, procs)
        quiet.start()
        time.sleep(a.quiet_s)
        print("without the flood, %.0f s: %s" % (a.quiet_s, quiet.stop().describe()))

        during = Window(a, url, procs)
        during.start()
        if a.sham:
            time.sleep(a.packets / a.rate)
            sender = {"sent": 0, "errors": 0, "seconds": a.packets / a.rate, "cpu": 0.0}
        else:
            sender = dict(zip(("sent", "errors", "seconds", "cpu"),
                              flood(a.port, seeds, a.packets, a.rate, rng, a.sender_nice)))
        during.stop()
        print("flood: %d packets sent (%d send errors) in %.0f s, %.0f packets/s, sender %.2f cores" % (
            sender["sent"], sender["errors"], sender["seconds"], sender["sent"] / sender["seconds"],
            sender["cpu"] / sender["seconds"]))
        print("during the flood: %s" % during.describe())
        if quiet.fused > 0:
            print("fused during / without the flood: %.0f %%" % (100.0 * during.fused / quiet.fused))
        time.sleep(2)
        alive = {n: p.poll() is None for n, p in procs.items()}
        print("alive after the flood: " + ", ".join("%s %s" % (n, "yes" if v else "NO (exit %s)" %
                                                                procs[n].returncode)
                                                    for n, v in alive.items()))
        listener = StatusListener(a.port)
        after = Window(a, url, procs)
        after.start()
        time.sleep(a.quiet_s)
        print("after the flood, %.0f s: %s" % (a.quiet_s, after.stop().describe()))
        heard = listener.status_sizes
        listener.stop()
        print("the monitor's status on the bus after the flood: %d messages%s" % (
            len(heard), " (last: %s, %d bytes)" % heard[-1] if heard else ""))
        final = status(a.bin, url, a.key_file)
        if not final:
            for name in ("monitor", "fusion"):
                with open(os.path.join(work, name + ".log"), errors="replace") as f:
                    print("%s log, last lines:\n  %s" % (name, "\n  ".join(f.read().splitlines()[-8:])))
        for name in ("fusion", "monitor"):
            d = final.get(name)
            if not d:
                print("%s: no status from the monitor" % name)
                continue
            print("%s: alive %s, messages malformed %d, foreign %d, bad version %d, rss %.0f MiB" % (
                name, d["alive"], d["messages_malformed"], d["messages_foreign"],
                d["messages_bad_version"], d["rss_bytes"] / 2**20))
            # With a rig key most of the flood ends here: dropped after reassembly, before decoding.
            auth = {k[len("auth_dropped_"):]: int(v) for k, v in d.get("counters", {}).items()
                    if k.startswith("auth_dropped_") and v}
            if auth:
                print("%s: dropped for their signature: %s" % (
                    name, ", ".join("%s %d" % kv for kv in sorted(auth.items()))))
        return 0 if all(alive.values()) else 1
    finally:
        for p in procs.values():
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
        for p in procs.values():
            try:
                p.wait(timeout=60)
            except subprocess.TimeoutExpired:
                p.kill()
        subprocess.run(["rm", "-rf", work])


if __name__ == "__main__":
    sys.exit(main())
