#!/usr/bin/env python3
"""Encodes depthfuse messages with the generated Python bindings and prints them as hex, one per
line, for the C++ side of the bindings test to decode. Usage: python_encode.py <build>/python"""
import sys

sys.path.insert(0, sys.argv[1])
import depthfuse  # noqa: E402

hb = depthfuse.heartbeat_t()
hb.protocol_version = depthfuse.heartbeat_t.PROTOCOL_VERSION
hb.utime = 1234567890
hb.name = "python"
hb.host = "remote"
hb.pid = 4242
hb.state = depthfuse.heartbeat_t.STATE_RUNNING
hb.point_count = 987654321
hb.last_error = "none \u00e9"
kv = depthfuse.key_value_t()
kv.key = "answer"
kv.value = 42.5
hb.counters = [kv]
hb.num_counters = 1
print(hb.encode().hex())

cmd = depthfuse.command_t()
cmd.protocol_version = depthfuse.command_t.PROTOCOL_VERSION
cmd.command_id = 77
cmd.target = "fusion"
cmd.action = depthfuse.command_t.ACTION_STOP
cmd.argument = ""
cmd.sender = "python@remote"
print(cmd.encode().hex())

# And back: decode what this script encoded (the bindings agree with themselves).
again = depthfuse.heartbeat_t.decode(hb.encode())
assert again.name == "python" and again.counters[0].value == 42.5
