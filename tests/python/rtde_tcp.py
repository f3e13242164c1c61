"""ur-rtde (SDU ur_rtde) reads where the controller's TCP is after a calibration wrote it:
`actual_TCP_pose` (base_from_tcp) and `actual_q`, through RTDEReceiveInterface.
Usage: rtde_tcp.py HOST"""
import json, sys
import rtde_receive

r = rtde_receive.RTDEReceiveInterface(sys.argv[1])
out = {"actual_q": r.getActualQ(), "actual_TCP_pose": r.getActualTCPPose()}
r.disconnect()
print(json.dumps(out))
