"""A PLC's side of `filmscope inspect`'s Modbus TCP server, with pymodbus.

Usage: modbus_plc.py HOST PORT SAMPLES

For each of SAMPLES: waits until the line waits for the trigger (register 1 = 1), sets
coil 0 ("sample in place"), waits until the sample counter (registers 2-3) moves on, then
reads the register map with functions 03 and 04 and prints one JSON line: the counter, the
verdict code, the alarm bits, the thickness mean/min/max, the index and the valid fraction
(f32, high word first), the last error, whether the coil was cleared. Exits 1 when the
server stops answering as expected within 60 s.
"""

import json
import struct
import sys
import time

from pymodbus.client import ModbusTcpClient

REGISTERS = 18


def f32(hi, lo):
    return struct.unpack(">f", struct.pack(">HH", hi, lo))[0]


def read(client):
    rr = client.read_holding_registers(0, count=REGISTERS)
    if rr.isError():
        raise SystemExit(f"read_holding_registers: {rr}")
    return rr.registers


def wait(client, what, cond):
    t0 = time.monotonic()
    while True:
        regs = read(client)
        if cond(regs):
            return regs
        if time.monotonic() - t0 > 60:
            raise SystemExit(f"never: {what} (registers {regs})")
        time.sleep(0.02)


def main():
    host, port, samples = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    client = ModbusTcpClient(host, port=port)
    if not client.connect():
        raise SystemExit(f"cannot connect to {host}:{port}")
    for _ in range(samples):
        regs = wait(client, "waiting for the trigger", lambda r: r[1] == 1)
        before = (regs[2] << 16) | regs[3]
        wr = client.write_coil(0, True)
        if wr.isError():
            raise SystemExit(f"write_coil: {wr}")
        regs = wait(client, "the next sample", lambda r: ((r[2] << 16) | r[3]) > before)
        inputs = client.read_input_registers(0, count=REGISTERS)
        coil = client.read_coils(0, count=1)
        print(json.dumps({
            "counter": (regs[2] << 16) | regs[3],
            "verdict": regs[4],
            "alarm_bits": regs[5],
            "thickness_mean": f32(regs[6], regs[7]),
            "thickness_min": f32(regs[8], regs[9]),
            "thickness_max": f32(regs[10], regs[11]),
            "index": f32(regs[12], regs[13]),
            "valid_fraction": f32(regs[14], regs[15]),
            "last_error": regs[16],
            "triggers": regs[17],
            "inputs_match": inputs.registers[2:17] == regs[2:17],
            "coil_cleared": not coil.bits[0],
        }), flush=True)
    client.close()


main()
