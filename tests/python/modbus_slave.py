"""Independent Modbus RTU slave for the HIL tests: pymodbus's own RTU server (a peer nobody
here wrote) plays a temperature module (instruments.md section 5) on the serial port given as
argv[1]; the registers of request k are computed here from k, so the test knows what each
answer held. Prints what it answered as JSON on stdout once it has handled `requests`
requests.

Usage: python3 modbus_slave.py <port> <unit> <channels> <requests> <exception_at,...>
"""

import asyncio
import json
import sys

from pymodbus.constants import ExcCodes
from pymodbus.datastore import ModbusServerContext
from pymodbus.server import ServerAsyncStop, StartAsyncSerialServer

try:
    from pymodbus import FramerType
except ImportError:  # older layout
    from pymodbus.framer import FramerType


def registers(k, channels):
    """Channel 0: 20.0 + k degC; 1: -(5.0 + 0.1 k) degC; the last: 0x8000 (open sensor);
    others 25.0 + i degC. Signed 16 bit in 0.1 degC."""
    out = []
    for i in range(channels):
        if i == channels - 1:
            out.append(0x8000)
        elif i == 0:
            out.append(200 + 10 * k)
        elif i == 1:
            out.append((-(50 + k)) & 0xFFFF)
        else:
            out.append(250 + 10 * i)
    return out


class Module(ModbusServerContext):
    """A context answering function 0x04 at registers 0..channels-1 (pymodbus calls
    `async_getValues` for reads; an `ExcCodes` return becomes an exception response)."""

    def __init__(self, unit, channels, requests, exception_at):  # pylint: disable=super-init-not-called
        self.simdevices = []
        self.old_simulator = True
        self.unit = unit
        self.channels = channels
        self.requests = requests
        self.exception_at = exception_at
        self.log = []

    def device_ids(self):
        return [self.unit]

    async def async_getValues(self, device_id, func_code, address, count=1):  # noqa: N802
        k = len(self.log)
        if k >= self.requests:
            return ExcCodes.DEVICE_BUSY
        if k == self.requests - 1:
            asyncio.get_running_loop().call_later(0.5, lambda: asyncio.ensure_future(ServerAsyncStop()))
        if k in self.exception_at:
            self.log.append({"k": k, "exception": 2})
            return ExcCodes.ILLEGAL_ADDRESS
        if func_code != 4 or address != 0 or count != self.channels or device_id != self.unit:
            self.log.append({"k": k, "unexpected": [device_id, func_code, address, count]})
            return ExcCodes.ILLEGAL_FUNCTION
        regs = registers(k, self.channels)
        self.log.append({"k": k, "registers": regs})
        return regs

    async def async_setValues(self, device_id, func_code, address, values):  # noqa: N802
        return ExcCodes.ILLEGAL_FUNCTION


async def main():
    port, unit, channels, requests = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
    exception_at = {int(x) for x in sys.argv[5].split(",") if x} if len(sys.argv) > 5 else set()
    ctx = Module(unit, channels, requests, exception_at)
    await StartAsyncSerialServer(context=ctx, framer=FramerType.RTU, port=port, baudrate=9600)
    print(json.dumps(ctx.log))


if __name__ == "__main__":
    asyncio.run(main())
