"""Independent SLCAN host for the HIL tests: python-can's own `slcan` interface opens the
simulated adapter on argv[1] (it sends the open commands itself) and listens until the
program-end trigger (event 5) or argv[2] seconds; prints the frames it received as JSON.

Usage: python3 slcan_host.py <serial port path> <seconds>
"""

import json
import sys
import time

import can


def main():
    port, secs = sys.argv[1], float(sys.argv[2])
    bus = can.Bus(interface="slcan", channel=port, bitrate=500000, sleep_after_open=0)
    frames = []
    deadline = time.monotonic() + secs
    try:
        while time.monotonic() < deadline:
            msg = bus.recv(timeout=0.1)
            if msg is None:
                continue
            frames.append({"id": msg.arbitration_id, "extended": msg.is_extended_id, "data": msg.data.hex()})
            if msg.arbitration_id == 0x181 and len(msg.data) == 8 and msg.data[0] == 5:
                break
    finally:
        bus.shutdown()
    print(json.dumps(frames))


if __name__ == "__main__":
    main()
