"""ur-rtde RTDEReceiveInterface against the simulator: default and explicit variable lists."""
import json, sys
import rtde_receive

host = sys.argv[1]
r = rtde_receive.RTDEReceiveInterface(host)
out = {
    "q": r.getActualQ(),
    "tcp": r.getActualTCPPose(),
    "robot_mode": r.getRobotMode(),
    "safety_mode": r.getSafetyMode(),
    "timestamp": r.getTimestamp(),
    "connected": r.isConnected(),
}
r.disconnect()
r2 = rtde_receive.RTDEReceiveInterface(host, 125.0, ["timestamp", "actual_q", "actual_TCP_pose", "output_double_register_12"])
out["explicit_q"] = r2.getActualQ()
out["explicit_tcp"] = r2.getActualTCPPose()
out["out_reg_12"] = r2.getOutputDoubleRegister(12)
r2.disconnect()
try:
    rtde_receive.RTDEReceiveInterface(host, 125.0, ["timestamp", "no_such_field"])
    out["not_found_raised"] = False
except Exception as e:  # ur_rtde raises on NOT_FOUND
    out["not_found_raised"] = True
    out["not_found_msg"] = str(e)
print(json.dumps(out))
