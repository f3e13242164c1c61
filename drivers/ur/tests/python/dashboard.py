"""ur-rtde DashboardClient: power on, brake release, load, play, stop, robotmode, safety status."""
import json, sys
import dashboard_client

host = sys.argv[1]
d = dashboard_client.DashboardClient(host)
d.connect()
out = {"connected": d.isConnected()}
out["mode_before"] = str(d.robotmode())
d.powerOn()
out["mode_powered"] = str(d.robotmode())
d.brakeRelease()
out["mode_released"] = str(d.robotmode())
out["safety_status"] = str(d.safetystatus())
d.loadURP("handeye.urp")
d.play()
out["running_after_play"] = d.running()
out["program_state"] = str(d.programState())
d.stop()
out["running_after_stop"] = d.running()
out["version"] = str(d.polyscopeVersion())
out["remote"] = d.isInRemoteControl()
d.disconnect()
print(json.dumps(out))
