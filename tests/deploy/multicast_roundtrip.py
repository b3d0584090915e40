"""Sends one datagram to an IPv4 multicast group with TTL 0 and receives it back, as LCM's udpm
transport does (join the group on the default interface, IP_MULTICAST_LOOP on).

usage: multicast_roundtrip.py GROUP PORT    exit 0: received; 1: no route / not received
"""
import socket
import struct
import sys

group, port = sys.argv[1], int(sys.argv[2])
rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM, socket.IPPROTO_UDP)
rx.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
rx.bind(("", port))
try:
    rx.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP,
                  struct.pack("4s4s", socket.inet_aton(group), socket.inet_aton("0.0.0.0")))
except OSError as e:
    print(f"join {group}: {e}")
    sys.exit(1)
rx.settimeout(2.0)

tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM, socket.IPPROTO_UDP)
tx.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 0)
tx.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_LOOP, 1)
payload = b"depthfuse-lcm-route test"
try:
    tx.sendto(payload, (group, port))
except OSError as e:
    print(f"send to {group}: {e}")
    sys.exit(1)
try:
    data, _ = rx.recvfrom(1024)
except socket.timeout:
    print(f"nothing received from {group} within 2 s")
    sys.exit(1)
if data != payload:
    print("received something else")
    sys.exit(1)
print(f"round trip through {group}:{port} ok")
