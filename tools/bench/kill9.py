#!/usr/bin/env python3
"""kill -9 the fusion daemon at random moments of a 30 Hz scan: how many frames each kill loses.

A synthetic capture publishes at 30 Hz (looping) into depthfuse-fusion recording a scan file. Each
round starts the daemon on the same file (it resumes from the last checkpoint), waits a random time
after the scan (re)started, kills it with SIGKILL and runs `depthfuse inspect` on the file. A frame
is lost when the daemon fused it (published its pose) but the file does not hold it, neither in
its last checkpoint nor in its frame redo log (schema 5): lost = (first frame of the round + poses
published - 1) - the newest frame the file holds after the kill. Then steady runs without kills
(alternating between the modes) give the fused rate and the writers' cost (the fusion daemon's
heartbeat counters): the CPU seconds its checkpoint and frame log threads spend per second.

--load N runs N busy loops (`yes > /dev/null`) beside the daemons for the whole run: with 2 on
this two-core machine, fusion, the capture and the writers' threads compete for cores that are
already taken (the frame log's commits are late, and what a kill loses depends on how late).

The modes run side by side in one invocation: the frame log (this build, committed every
--log-interval-s, full checkpoints every 30 s), this build without the log and 30 s checkpoints
(steady runs only: the fused rate without incremental durability), and --baseline-bin (the
binaries of an earlier build, checkpoints every --baseline-interval-s, --baseline-kills rounds;
their configuration has no frame log key).

  tools/bench/kill9.py [--kills 100] [--bin build/bin] [--baseline-bin DIR]
                       [--baseline-interval-s 30] [--baseline-kills N] [--steady-s 30]
                       [--log-interval-s 1] [--checkpoint-interval-s 30]
                       [--steady-runs 2] [--min-s 0.1] [--max-s 6] [--scene room] [--load N]
                       [--lcm URL] [--workdir DIR]
"""
import argparse
import json
import os
import random
import re
import shutil
import signal
import statistics
import subprocess
import sys
import threading
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
sys.path.insert(0, HERE)
import busy_load  # noqa: E402


class Watcher:
    """Pose and fusion heartbeat messages, stamped with their arrival (tools/lcm/watch.py)."""

    def __init__(self, url, python_dir):
        self.lock = threading.Lock()
        self.poses = []        # arrival times
        self.heartbeats = []   # (arrival, message)
        self.proc = subprocess.Popen(
            [sys.executable, os.path.join(ROOT, "tools", "lcm", "watch.py"), "--lcm", url,
             "--python-dir", python_dir, "--channel", "DEPTHFUSE_(POSE|HEARTBEAT)"],
            stdout=subprocess.PIPE, text=True)
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self):
        for line in self.proc.stdout:
            now = time.monotonic()
            try:
                rec = json.loads(line)
            except ValueError:
                continue
            with self.lock:
                if rec.get("channel") == "DEPTHFUSE_POSE":
                    self.poses.append(now)
                elif rec.get("channel") == "DEPTHFUSE_HEARTBEAT" and rec["message"].get("name") == "fusion":
                    self.heartbeats.append((now, rec["message"]))

    def poses_between(self, t0, t1):
        with self.lock:
            return [t for t in self.poses if t0 <= t <= t1]

    def heartbeats_between(self, t0, t1):
        with self.lock:
            return [(t, m) for t, m in self.heartbeats if t0 <= t <= t1]

    def stop(self):
        self.proc.terminate()
        self.proc.wait()


def counter(hb, name):
    for c in hb.get("counters", []):
        if c.get("key") == name:
            return c.get("value")
    return None


def wait_for_line(path, pattern, timeout_s):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        with open(path, errors="replace") as f:
            m = re.search(pattern, f.read())
        if m:
            return m
        time.sleep(0.02)
    return None


def inspect(cli, db):
    """(exit code, the newest frame the file holds, output) of `depthfuse inspect`: the last
    checkpoint's, or the frame log's last record after it."""
    r = subprocess.run([cli, "inspect", db], capture_output=True, text=True)
    m = re.search(r"checkpoints +\d+, last #\d+ at .*\([\w ]+, frame (\d+)\)", r.stdout)
    last = int(m.group(1)) if m else 0
    log = re.search(r"frame log +\d+ frames \((\d+)-(\d+)\)", r.stdout)
    if log:
        last = max(last, int(log.group(2)))
    return r.returncode, last, r.stdout + r.stderr


class Mode:
    """One way of running the daemon: its binaries (and their CLI) and checkpoint interval."""

    def __init__(self, name, bin_dir, interval_s, args, kills, log_interval_s=None):
        self.name, self.args, self.kills = name, args, kills
        self.work = os.path.join(args.workdir, name.replace(" ", "-").replace("/", "-"))
        shutil.rmtree(self.work, ignore_errors=True)
        os.makedirs(self.work)
        self.cfg = os.path.join(self.work, "depthfuse.toml")
        with open(self.cfg, "w") as f:
            f.write("[lcm]\nkey_file = \"\"\n[fusion_daemon]\ncheckpoint_interval_s = %g\nscan_dir = \"%s\"\n" %
                    (interval_s, os.path.join(self.work, "scans")))
            if log_interval_s is not None:  # builds before the frame log do not know the key
                f.write("frame_log_interval_s = %g\n" % log_interval_s)
        self.db = os.path.join(self.work, "scan.db")
        self.fusion = os.path.join(bin_dir, "depthfuse-fusion")
        self.cli = os.path.join(bin_dir, "depthfuse")  # inspect of the schema these binaries write
        self.rates, self.heartbeats, self.writer_cpu, self.log_wait = [], [], [], []
        self.proc = None

    def start(self, log):
        out = open(log, "w")
        self.proc = subprocess.Popen([self.fusion, "--config", self.cfg, "--lcm", self.args.lcm, "--key-file", "",
                                      "--scan-db", self.db, "--autostart", "k9"],
                                     stdout=out, stderr=subprocess.STDOUT)
        return self.proc

    def remove_scan(self):
        for suffix in ("", "-wal", "-shm"):
            if os.path.exists(self.db + suffix):
                os.remove(self.db + suffix)


class Kills:
    """One mode's kill rounds so far."""

    def __init__(self, mode):
        self.mode = mode
        self.lost, self.inspect_ok, self.rounds, self.problems = [], 0, 0, []
        self.expected_start = 1

    def result(self):
        lost = self.lost
        return {
            "mode": self.mode.name, "kills": self.rounds, "inspect_ok": self.inspect_ok, "lost": lost,
            "lost_max": max(lost) if lost else 0, "lost_mean": statistics.mean(lost) if lost else 0,
            "lost_over_30": sum(1 for x in lost if x > 30), "problems": self.problems,
        }


def kill_round(k, i, args, watcher):
    """Round i of a mode: start the daemon on its file, kill it at a random moment, inspect."""
    mode = k.mode
    log = os.path.join(mode.work, "fusion-%d.log" % i)
    t_start = time.monotonic()
    proc = mode.start(log)
    m = wait_for_line(log, r"scan k9 (started|resumed at frame (\d+))", 60)
    if not m:
        proc.kill()
        proc.wait()
        k.problems.append("round %d: the daemon did not start its scan (%s)" % (i, log))
        return
    first = int(m.group(2)) if m.group(2) else 1
    if first != k.expected_start:
        k.problems.append("round %d: resumed at frame %d, the file's last checkpoint says %d" %
                          (i, first, k.expected_start))
    # The random moment counts from the round's first fused frame: resuming a big map on a
    # loaded machine takes a while, and a kill before fusion restarts would lose nothing.
    deadline = time.monotonic() + 60
    while not watcher.poses_between(t_start, time.monotonic()) and time.monotonic() < deadline:
        time.sleep(0.01)
    time.sleep(random.uniform(args.min_s, args.max_s))
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    t_kill = time.monotonic()
    time.sleep(0.3)  # poses already on the wire
    fused = len(watcher.poses_between(t_start, t_kill + 0.3))
    code, last, out = inspect(mode.cli, mode.db)
    k.rounds += 1
    if code == 0:
        k.inspect_ok += 1
    else:
        k.problems.append("round %d: inspect exit %d:\n%s" % (i, code, out))
    last_fused = first + fused - 1
    k.lost.append(max(0, last_fused - last))
    k.expected_start = last + 1
    print("%-14s kill %3d: frames %d-%d fused, file at frame %d: %d lost, inspect %s" %
          (mode.name, i + 1, first, last_fused, last, k.lost[-1], "ok" if code == 0 else "FAILED"),
          flush=True)


def distribution(lost):
    """Kills by frames lost, in bins of 5 (the last: over 30)."""
    if not lost:
        return "-"
    bins = [(0, 5), (6, 10), (11, 15), (16, 20), (21, 25), (26, 30)]
    parts = ["%d-%d: %d" % (a, b, sum(1 for x in lost if a <= x <= b)) for a, b in bins]
    parts.append("> 30: %d" % sum(1 for x in lost if x > 30))
    return ", ".join(parts)


def steady(mode, args, watcher, run):
    """A fresh scan without kills for --steady-s: its fused rate and the heartbeats' figures."""
    mode.remove_scan()
    log = os.path.join(mode.work, "fusion-steady-%d.log" % run)
    proc = mode.start(log)
    wait_for_line(log, r"scan k9 started", 60)
    t0 = time.monotonic()
    time.sleep(args.steady_s)
    t1 = time.monotonic()
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    mode.rates.append(len(watcher.poses_between(t0, t1)) / (t1 - t0))
    hbs = watcher.heartbeats_between(t0, t1)
    mode.heartbeats += [m for _, m in hbs]
    mode.writer_cpu.append(writer_cpu(hbs))
    if len(hbs) >= 2:
        (ta, a), (tb, b) = hbs[0], hbs[-1]
        mode.log_wait.append(((counter(b, "frame_log_wait_s") or 0) - (counter(a, "frame_log_wait_s") or 0)) / (tb - ta))
    print("%-14s steady run %d: %.1f frames fused per second, writer threads %.0f ms CPU per second, "
          "load average %s" % (mode.name, run + 1, mode.rates[-1], 1e3 * mode.writer_cpu[-1],
                                " ".join("%.2f" % x for x in os.getloadavg())), flush=True)


def writer_cpu(hbs):
    """Seconds the writer threads work per second of scan: from the cumulative counters of the
    checkpoint and frame log threads where the build has them, else the last checkpoint's encode
    and write times times the checkpoints committed per second."""
    if len(hbs) < 2:
        return 0.0
    (ta, a), (tb, b) = hbs[0], hbs[-1]
    cum = ["checkpoint_encode_s", "checkpoint_write_s", "frame_log_encode_s", "frame_log_write_s"]
    if counter(b, "checkpoint_encode_s") is not None:
        return sum((counter(b, k) or 0) - (counter(a, k) or 0) for k in cum) / (tb - ta)
    per = [(counter(m, "checkpoint_encode_ms") or 0) + (counter(m, "checkpoint_write_ms") or 0)
           for _, m in hbs]
    n = (counter(b, "checkpoints_written") or 0) - (counter(a, "checkpoints_written") or 0)
    return n / (tb - ta) * statistics.mean(per) * 1e-3


def figures(mode, counter_name):
    vals = [v for v in (counter(h, counter_name) for h in mode.heartbeats) if v]
    return (statistics.mean(vals), max(vals)) if vals else (0.0, 0.0)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kills", type=int, default=100)
    ap.add_argument("--bin", default=os.path.join(ROOT, "build", "bin"))
    ap.add_argument("--baseline-bin", default="", help="binaries of an earlier build ('' = skip)")
    ap.add_argument("--baseline-interval-s", type=float, default=30.0)
    ap.add_argument("--baseline-kills", type=int, default=-1, help="default: --kills")
    ap.add_argument("--log-interval-s", type=float, default=1.0, help="this build's frame log commits")
    ap.add_argument("--checkpoint-interval-s", type=float, default=30.0, help="this build's full checkpoints")
    ap.add_argument("--python-dir", default=os.path.join(ROOT, "build", "python"))
    ap.add_argument("--steady-s", type=float, default=30.0)
    ap.add_argument("--steady-runs", type=int, default=2)
    ap.add_argument("--min-s", type=float, default=0.1, help="earliest kill after the round's first fused frame")
    ap.add_argument("--max-s", type=float, default=6.0, help="latest kill after the round's first fused frame")
    ap.add_argument("--scene", default="room")
    ap.add_argument("--load", type=int, default=0, help="busy loops beside the daemons (2: both cores)")
    ap.add_argument("--lcm", default="udpm://239.255.76.67:%d?ttl=0&recv_buf_size=4194304" % (7700 + os.getpid() % 200))
    ap.add_argument("--workdir", default="/tmp/depthfuse-kill9")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    random.seed(args.seed)

    watcher = Watcher(args.lcm, args.python_dir)
    capture = subprocess.Popen(
        [os.path.join(args.bin, "depthfuse-capture"), "--source", "synthetic:%s?frames=600" % args.scene,
         "--rate", "30", "--loop", "--lcm", args.lcm, "--key-file", "", "--color", "none"],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    modes = [Mode("log %gs/%gs" % (args.log_interval_s, args.checkpoint_interval_s), args.bin,
                  args.checkpoint_interval_s, args, args.kills, log_interval_s=args.log_interval_s),
             Mode("no log/%gs" % args.checkpoint_interval_s, args.bin, args.checkpoint_interval_s,
                  args, 0, log_interval_s=0)]
    if args.baseline_bin:
        modes.append(Mode("baseline %gs" % args.baseline_interval_s, args.baseline_bin,
                          args.baseline_interval_s, args,
                          args.kills if args.baseline_kills < 0 else args.baseline_kills))
    kills = [Kills(m) for m in modes]
    load = busy_load.BusyLoad(args.load)
    try:
        # The modes' rounds alternate, so that a shared machine's load weighs on them alike.
        for i in range(max(m.kills for m in modes)):
            for k in kills:
                if i < k.mode.kills:
                    kill_round(k, i, args, watcher)
        # Alternating, so that the load of a shared machine weighs on both alike.
        for run in range(args.steady_runs):
            for m in modes:
                steady(m, args, watcher, run)
    finally:
        load.stop()
        for m in modes:
            if m.proc and m.proc.poll() is None:
                m.proc.kill()
        capture.terminate()
        capture.wait()
        watcher.stop()
    results = [k.result() for k in kills]

    print("\nkills at random moments %.1f-%.1f s after each round's first fused frame; capture 30 Hz "
          "synthetic %s; %d busy loops beside; load average at the end %s" %
          (args.min_s, args.max_s, args.scene, args.load, " ".join("%.2f" % x for x in os.getloadavg())))
    print("| mode | kills | inspect ok | frames lost max | mean | kills losing > 30 | fused rate "
          "(%d x %.0f s, alternating) | writer threads' CPU per second | checkpoint on the fusion "
          "thread (mean / max) | encode | write |" % (args.steady_runs, args.steady_s))
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for m, r in zip(modes, results):
        rates = "%.1f fps (%s)" % (statistics.mean(m.rates), ", ".join("%.1f" % x for x in m.rates)) if m.rates else "-"
        cpu = "%.0f ms (%s)" % (1e3 * statistics.mean(m.writer_cpu), ", ".join("%.0f" % (1e3 * x) for x in m.writer_cpu)) if m.writer_cpu else "-"
        print("| %s | %d | %d | %d | %.1f | %d | %s | %s | %.1f / %.1f ms | %.0f / %.0f ms | %.0f / %.0f ms |" %
              (r["mode"], r["kills"], r["inspect_ok"], r["lost_max"], r["lost_mean"], r["lost_over_30"], rates, cpu,
               *figures(m, "checkpoint_snapshot_ms"), *figures(m, "checkpoint_encode_ms"),
               *figures(m, "checkpoint_write_ms")))
    for r in results:
        if r["kills"]:
            print("%s: frames lost per kill: %s" % (r["mode"], distribution(r["lost"])))
    for m in modes:
        lag = [counter(h, "frame_log_max_lag_ms") for h in m.heartbeats]
        lag = [v for v in lag if v is not None]
        if lag:  # builds before issue 36 do not count it
            print("%s: steady runs: the frame log's most waited frame %.0f ms; fusion waited for the "
                  "log %.0f ms per second" % (m.name, max(lag), 1e3 * (statistics.mean(m.log_wait) if m.log_wait else 0)))
    for r in results:
        for p in r["problems"]:
            print("%s: %s" % (r["mode"], p))
    return 0 if all(not r["problems"] and r["lost_over_30"] == 0 for r in results[:1]) else 1


if __name__ == "__main__":
    sys.exit(main())
