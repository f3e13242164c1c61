"""python-urx (PyPI `urx`) against the simulated controller: it reads the secondary interface's
robot state (joint data, Cartesian info) and sends one-line URScript programs to 30002.

Usage: urx_client.py HOST. Prints one JSON object; tests/e2e/ur_clients.rs checks the values
against the simulator's own state."""
import json
import sys
import time

import urx

host = sys.argv[1]
t = time.monotonic()
robot = urx.URRobot(host)
out = {"connect_seconds": time.monotonic() - t, "running": robot.is_running()}
out["getj"] = robot.getj(wait=True)
out["getl"] = robot.getl(wait=True)

target_j = [a + d for a, d in zip(out["getj"], [0.25, -0.15, 0.2, 0.1, -0.2, 0.3])]
robot.movej(target_j, acc=1.4, vel=1.0)
time.sleep(0.3)  # the 10 Hz state, read after the move ended
out["movej_target"] = target_j
out["after_movej"] = robot.getj(wait=True)

target_l = list(robot.getl(wait=True))
target_l[0] += 0.04
target_l[2] -= 0.05
robot.movel(target_l, acc=0.5, vel=0.2)
time.sleep(0.3)
out["movel_target"] = target_l
out["after_movel"] = robot.getl(wait=True)
out["after_movel_j"] = robot.getj(wait=True)

tcp = (0.0, 0.0, 0.1, 0.0, 0.0, 0.0)
robot.set_tcp(tcp)
time.sleep(0.3)
out["tcp"] = list(tcp)
out["getl_with_tcp"] = robot.getl(wait=True)
out["getj_with_tcp"] = robot.getj(wait=True)
robot.close()
print(json.dumps(out))
