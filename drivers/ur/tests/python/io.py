"""ur-rtde RTDEIOInterface writes input registers; a secondary program copies them to output
registers; RTDEReceiveInterface (explicit recipe) reads them back."""
import json, socket, sys, time
import rtde_io, rtde_receive

host = sys.argv[1]
io = rtde_io.RTDEIOInterface(host)
ok_d = io.setInputDoubleRegister(20, 1.25)
ok_i = io.setInputIntRegister(19, 42)
time.sleep(0.1)
s = socket.create_connection((host, 30002), timeout=5)
s.sendall(b"sec copy():\n  write_output_float_register(12, read_input_float_register(20))\n"
          b"  write_output_integer_register(12, read_input_integer_register(19))\nend\n")
r = rtde_receive.RTDEReceiveInterface(host, 125.0, ["timestamp", "output_double_register_12", "output_int_register_12"])
deadline = time.time() + 3
d = i = None
while time.time() < deadline:
    d = r.getOutputDoubleRegister(12)
    i = r.getOutputIntRegister(12)
    if d == 1.25 and i == 42:
        break
    time.sleep(0.05)
s.close()
r.disconnect()
io.disconnect()
print(json.dumps({"ok_d": ok_d, "ok_i": ok_i, "d": d, "i": i}))
