"""Independent SLCAN peer for the HIL tests: python-can's own `slcan` interface writes CNC
trigger frames (payload packed here with `struct`, from instruments.md §4, not with our
encoder) to the serial port given as argv[1]; prints what it sent as JSON on stdout.

Usage: python3 slcan_peer.py <serial port path>
"""

import json
import struct
import sys
import time

import can

TRIGGER_ID = 0x181


def payload(event, pose, nc_ms):
    # byte 0 event, byte 1 reserved 0, bytes 2-3 pose u16 LE, bytes 4-7 NC clock ms u32 LE
    return struct.pack("<BBHI", event, 0, pose, nc_ms & 0xFFFFFFFF)


def main():
    port = sys.argv[1]
    bus = can.Bus(interface="slcan", channel=port, bitrate=500000, sleep_after_open=0)
    sent = []
    others = []
    nc = 4294967295 - 1500  # the NC clock wraps during the program

    def trig(event, pose):
        nonlocal nc
        msg = can.Message(arbitration_id=TRIGGER_ID, is_extended_id=False, data=payload(event, pose, nc))
        bus.send(msg)
        sent.append({"event": event, "pose": pose, "nc_ms": nc & 0xFFFFFFFF})
        nc = (nc + 250) & 0xFFFFFFFF

    trig(4, 0)
    for pose in range(1, 6):
        trig(1, pose)
        trig(2, pose)
        trig(3, pose)
        if pose == 2:
            # Not ours: another identifier, and the same identifier as an extended frame.
            bus.send(can.Message(arbitration_id=0x182, is_extended_id=False, data=payload(2, 9, 1)))
            bus.send(can.Message(arbitration_id=TRIGGER_ID, is_extended_id=True, data=payload(2, 9, 1)))
            others.append("0x182 and extended 0x181")
        if pose == 4:
            # Ours but malformed: DLC 3.
            bus.send(can.Message(arbitration_id=TRIGGER_ID, is_extended_id=False, data=bytes([2, 0, 4])))
            others.append("dlc 3")
    trig(6, 5)
    trig(5, 0)
    time.sleep(0.2)
    bus.shutdown()
    print(json.dumps({"sent": sent, "others": others}))


if __name__ == "__main__":
    main()
