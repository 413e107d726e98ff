#!/usr/bin/env python3
"""A plain Python acquisition daemon: the comparison peer of the pipeline bench.

What anyone would write with pyserial: one thread per instrument port, each configuring its
device (docs/instruments.md), then reading whatever has arrived (`read(in_waiting or 1)`),
cutting it into lines (LI-80, PSD-2) or COBS frames (CB-3), parsing each minimally (fields to
numbers, COBS decoded and unpacked, no checksum) and appending one CSV line per sample to a
file. The SLCAN adapter is opened like the daemon opens it, which starts the simulated program;
its trigger frames are written too, and the program-end frame stops everything.

    plain_daemon.py OUT_DIR LI80 CB3 PSD SLCAN LI80_HZ CB3_HZ PSD_HZ

Prints `samples N` (instrument samples written) on exit.
"""
import os
import struct
import sys
import threading

import serial

stop = threading.Event()
# The instruments stream before the SLCAN channel opens (and the program starts).
ready = threading.Barrier(4)


def port(path):
    return serial.Serial(path, 115200, timeout=0.2)


def command(ser, line, answers=1):
    ser.write(line.encode())
    for _ in range(answers):
        ser.readline()


def chunks(ser):
    ready.wait()
    while not stop.is_set():
        data = ser.read(ser.in_waiting or 1)
        if data:
            yield data


def li80(path, hz, out):
    ser = port(path)
    command(ser, "STREAM OFF\n")
    ser.reset_input_buffer()
    for c in (f"RATE {hz}\n", "DATUM\n", "STREAM ON\n"):
        command(ser, c)
    n, rest = 0, b""
    with open(out, "w") as f:
        for data in chunks(ser):
            lines = (rest + data).split(b"\n")
            rest = lines.pop()
            for line in lines:
                if line.startswith(b"$POS,"):
                    try:
                        body = line[5:line.index(b"*")].split(b",")
                        seq, t_us, raw_nm, sig = (int(x) for x in body[:4])
                        flags = body[4].decode()
                    except (ValueError, IndexError):
                        continue
                    f.write(f"{seq},{t_us},{raw_nm * 1e-3},{sig},{flags}\n")
                    n += 1
    ser.write(b"STREAM OFF\n")
    return n


def cobs_decode(frame):
    out, i = bytearray(), 0
    while i < len(frame):
        code = frame[i]
        out += frame[i + 1:i + code]
        i += code
        if code < 0xFF and i < len(frame):
            out.append(0)
    return bytes(out)


def cb3(path, hz, out):
    ser = port(path)
    ser.write(b"STOP\n")
    ser.read_until(b"\x00")
    ser.reset_input_buffer()
    for c in (f"RATE {hz}\n", "START\n"):
        ser.write(c.encode())
        ser.read_until(b"\x00")
    n, rest = 0, b""
    sample = struct.Struct("<BHIiiiB")
    with open(out, "w") as f:
        for data in chunks(ser):
            frames = (rest + data).split(b"\x00")
            rest = frames.pop()
            for fr in frames:
                p = cobs_decode(fr)
                if len(p) == 22 and p[0] == 1:  # a 22-byte sample payload
                    _, seq, t_us, c0, c1, c2, flags = sample.unpack_from(p)
                    k = 10.0 / 8388608
                    f.write(f"{seq},{t_us},{c0 * k},{c1 * k},{c2 * k},{flags}\n")
                    n += 1
    ser.write(b"STOP\n")
    return n


def psd(path, hz, out):
    ser = port(path)
    ser.write(b"INIT:CONT OFF\n")
    command(ser, "*OPC?\n")
    ser.reset_input_buffer()
    ser.write(f"CONF:RATE {hz}\nINIT:CONT ON\n".encode())
    n, rest = 0, b""
    with open(out, "w") as f:
        for data in chunks(ser):
            lines = (rest + data).split(b"\n")
            rest = lines.pop()
            for line in lines:
                if line.startswith(b"D,"):
                    try:
                        seq, t_us, x1, x2, y1, y2, head = (int(x) for x in line[2:].split(b","))
                    except ValueError:
                        continue
                    x = 5000.0 * (x2 - x1) / max(x1 + x2, 1)
                    y = 5000.0 * (y2 - y1) / max(y1 + y2, 1)
                    f.write(f"{seq},{t_us},{x},{y},{head * 1e-3}\n")
                    n += 1
    ser.write(b"INIT:CONT OFF\n")
    return n


def triggers(path, out):
    ser = port(path)
    ready.wait()
    for c in ("C\r", "S6\r", "O\r"):
        ser.write(c.encode())
        ser.read_until(b"\r")
    rest = b""
    with open(out, "w") as f:
        while not stop.is_set():
            data = ser.read(ser.in_waiting or 1)
            msgs = (rest + data).split(b"\r")
            rest = msgs.pop()
            for m in msgs:
                if m.startswith(b"t") and len(m) >= 21:
                    try:
                        d = bytes.fromhex(m[5:21].decode())
                    except ValueError:
                        continue
                    event, _, pose, nc_ms = struct.unpack("<BBHI", d)
                    f.write(f"{event},{pose},{nc_ms}\n")
                    if event == 5:
                        stop.set()
    ser.write(b"C\r")


def main():
    out_dir, li80_p, cb3_p, psd_p, can_p = sys.argv[1:6]
    li80_hz, cb3_hz, psd_hz = (int(x) for x in sys.argv[6:9])
    counts = {}

    def run(name, f, *args):
        counts[name] = f(*args, os.path.join(out_dir, name + ".csv"))

    threads = [
        threading.Thread(target=run, args=("li80", li80, li80_p, li80_hz)),
        threading.Thread(target=run, args=("cb3", cb3, cb3_p, cb3_hz)),
        threading.Thread(target=run, args=("psd", psd, psd_p, psd_hz)),
    ]
    for t in threads:
        t.start()
    triggers(can_p, os.path.join(out_dir, "triggers.csv"))
    for t in threads:
        t.join()
    print(f"samples {sum(counts.values())}")


if __name__ == "__main__":
    main()
