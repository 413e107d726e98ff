"""Independent Modbus RTU master for the HIL tests: pymodbus's own RTU client reads the
simulated temperature module on the serial port argv[1] `reads` times, one input-register
read of `channels` registers from 0 each, and prints each outcome as JSON on stdout:
{"registers": [...]}, {"exception": code} or {"error": text} (no answer or a bad frame).

Usage: python3 modbus_master.py <port> <unit> <channels> <reads>
"""

import json
import sys

from pymodbus.client import ModbusSerialClient
from pymodbus.exceptions import ModbusException

try:
    from pymodbus import FramerType
except ImportError:  # older layout
    from pymodbus.framer import FramerType


def main():
    port, unit, channels, reads = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
    client = ModbusSerialClient(port=port, framer=FramerType.RTU, baudrate=9600, timeout=0.5, retries=0)
    if not client.connect():
        sys.exit(f"cannot open {port}")
    out = []
    for _ in range(reads):
        try:
            try:
                rr = client.read_input_registers(0, count=channels, device_id=unit)
            except TypeError:  # pymodbus before 3.10 called it `slave`
                rr = client.read_input_registers(0, count=channels, slave=unit)
        except ModbusException as e:
            out.append({"error": str(e)})
            continue
        if rr.isError():
            code = getattr(rr, "exception_code", None)
            out.append({"exception": int(code)} if code is not None else {"error": str(rr)})
        else:
            out.append({"registers": list(rr.registers)})
    client.close()
    print(json.dumps(out))


if __name__ == "__main__":
    main()
