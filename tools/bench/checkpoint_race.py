#!/usr/bin/env python3
"""Checkpoint commands every 0.15 s, then stop: does every stop succeed and every command get an answer?

A synthetic capture publishes at 30 Hz (looping) into one depthfuse-fusion recording scan files
(the frame redo log committing every second, full checkpoints every 30 s). Each round starts a
scan, sends `depthfuse scan checkpoint` every --interval-s (each command in its own client
process, not waiting for the one before) for --commands commands, then, once they are answered,
`depthfuse scan stop`. A round passes when every command was answered (exit 0: accepted, or 1: rejected with a
reason; 3 is no answer), the stop succeeded ("saved"), and the next round's start is answered.
The scan's SQLite connection being used by two threads at once showed here as stops failing with
"cannot start a transaction within a transaction", or a daemon answering nothing for 90 s.

  tools/bench/checkpoint_race.py [--rounds 100] [--commands 8] [--interval-s 0.15] [--bin build/bin]
                                 [--scene room] [--load N] [--lcm URL] [--workdir DIR]

Prints one line per round and a summary; exit 0 when every round passed.
"""
import argparse
import os
import shutil
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
sys.path.insert(0, HERE)
import busy_load  # noqa: E402


def scan(cli, lcm, cfg, *args, timeout_s=10):
    return subprocess.Popen([cli, "scan", *args, "--lcm", lcm, "--config", cfg, "--timeout", str(timeout_s)],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=100)
    ap.add_argument("--commands", type=int, default=8, help="checkpoint commands per round")
    ap.add_argument("--interval-s", type=float, default=0.15)
    ap.add_argument("--bin", default=os.path.join(ROOT, "build", "bin"))
    ap.add_argument("--scene", default="room", help="the synthetic scene the capture renders")
    ap.add_argument("--load", type=int, default=0, help="busy loops beside the daemons (2: both cores)")
    ap.add_argument("--lcm", default="udpm://239.255.76.67:%d?ttl=0&recv_buf_size=4194304" % (7900 + os.getpid() % 90))
    ap.add_argument("--workdir", default="/tmp/depthfuse-checkpoint-race")
    args = ap.parse_args()

    shutil.rmtree(args.workdir, ignore_errors=True)
    os.makedirs(args.workdir)
    cfg = os.path.join(args.workdir, "depthfuse.toml")
    with open(cfg, "w") as f:
        f.write('[lcm]\nkey_file = ""\n[fusion_daemon]\nscan_dir = "%s"\nmin_scan_interval_s = 0\n' %
                os.path.join(args.workdir, "scans"))
    cli = os.path.join(args.bin, "depthfuse")
    log = open(os.path.join(args.workdir, "fusion.log"), "w")
    fusion = subprocess.Popen([os.path.join(args.bin, "depthfuse-fusion"), "--config", cfg, "--lcm", args.lcm],
                              stdout=log, stderr=subprocess.STDOUT)
    capture = subprocess.Popen(
        [os.path.join(args.bin, "depthfuse-capture"), "--config", cfg, "--source",
         "synthetic:%s?frames=300" % args.scene, "--rate", "30", "--loop", "--lcm", args.lcm, "--color", "none"],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    load = busy_load.BusyLoad(args.load)
    failures, rejected, unanswered, stops_failed, started = [], [], 0, 0, 0
    t_begin = time.monotonic()
    try:
        time.sleep(1.0)
        for r in range(args.rounds):
            start = scan(cli, args.lcm, cfg, "start", "race%d" % r)
            out, _ = start.communicate()
            if start.returncode != 0:
                failures.append("round %d: start exit %d: %s" % (r, start.returncode, out.strip()))
                if start.returncode == 3:
                    unanswered += 1
                print("round %3d: start FAILED (exit %d) %s" % (r + 1, start.returncode, out.strip()), flush=True)
                continue
            started += 1
            commands = []
            for _ in range(args.commands):
                commands.append(scan(cli, args.lcm, cfg, "checkpoint"))
                time.sleep(args.interval_s)
            codes = []
            outs = [c.communicate()[0] for c in commands]
            # The stop after every checkpoint command was answered: clients started 0.15 s apart
            # may reach the daemon in another order.
            stop = scan(cli, args.lcm, cfg, "stop", timeout_s=60)
            for c, out in zip(commands, outs):
                codes.append(c.returncode)
                if c.returncode == 3:
                    unanswered += 1
                    failures.append("round %d: a checkpoint command had no answer: %s" % (r, out.strip()))
                elif c.returncode != 0:
                    rejected.append("round %d: %s" % (r, out.strip()))
            out, _ = stop.communicate()
            ok = stop.returncode == 0 and " saved" in out
            if not ok:
                stops_failed += 1
                if stop.returncode == 3:
                    unanswered += 1
                failures.append("round %d: stop exit %d: %s" % (r, stop.returncode, out.strip()))
            print("round %3d: checkpoint commands %s, stop %s" %
                  (r + 1, " ".join(str(c) for c in codes), "ok" if ok else "FAILED: " + out.strip()),
                  flush=True)
    finally:
        load.stop()
        capture.terminate()
        fusion.terminate()
        capture.wait()
        fusion.wait()
    print("\n%d rounds (%d started) of %d checkpoint commands %.2f s apart then stop, %d busy loops, "
          "%.0f s: %d stops failed, %d commands unanswered" %
          (args.rounds, started, args.commands, args.interval_s, args.load, time.monotonic() - t_begin,
           stops_failed, unanswered))
    for f in failures:
        print(f)
    for f in rejected[:5]:
        print("rejected (answered): " + f)
    return 0 if not failures else 1


if __name__ == "__main__":
    sys.exit(main())
