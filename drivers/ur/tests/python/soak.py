"""Soak load for `handeye sim robot` memory measurements (not run by `cargo test`).

Usage: soak.py HOST SECONDS
Keeps an RTDEReceiveInterface streaming (default 58-field recipe, 500 Hz), reconnects a second
receiver every few seconds, polls the dashboard and sends small scripts, so every server path
is exercised. Prints a line per 10 s.
"""
import socket, sys, time
import dashboard_client, rtde_io, rtde_receive

host, seconds = sys.argv[1], float(sys.argv[2])
recv = rtde_receive.RTDEReceiveInterface(host)
io = rtde_io.RTDEIOInterface(host)
dash = dashboard_client.DashboardClient(host)
dash.connect()
prim = socket.create_connection((host, 30001), timeout=5)
prim.setblocking(False)
start = last = time.time()
n = 0
while time.time() - start < seconds:
    n += 1
    recv.getActualQ()
    dash.robotmode()
    io.setInputDoubleRegister(20, float(n))
    if n % 20 == 0:
        prim.sendall(b"sec s():\n  write_output_float_register(12, read_input_float_register(20))\n  textmsg(\"tick\")\nend\n")
        try:
            while prim.recv(65536):
                pass
        except BlockingIOError:
            pass
    if n % 100 == 0:
        r2 = rtde_receive.RTDEReceiveInterface(host, 125.0, ["timestamp", "actual_q"])
        r2.disconnect()
    if time.time() - last > 10:
        last = time.time()
        print(f"{last - start:.0f}s iterations={n}", flush=True)
    time.sleep(0.02)
print("done", flush=True)
