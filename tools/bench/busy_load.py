"""Busy loops beside a benchmark's daemons: the rig's cores taken by something else.

BusyLoad(n) starts n `yes > /dev/null` processes at the default priority, each under `timeout` so
that none outlives a benchmark that dies (--max-s, default 2 hours); stop() ends them.
"""
import subprocess


class BusyLoad:
    def __init__(self, n, max_s=7200):
        self.procs = [subprocess.Popen(["timeout", str(int(max_s)), "yes"], stdout=subprocess.DEVNULL)
                      for _ in range(n)]

    def stop(self):
        for p in self.procs:
            p.terminate()
        for p in self.procs:
            p.wait()
        self.procs = []
