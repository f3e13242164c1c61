"""ur-rtde DashboardClient: power on, brake release, load, play, stop, robotmode, safety status."""
import json, sys, time
import dashboard_client


def wait_for_mode(d, mode, limit_s=10.0):
    """Polls robotmode as a client of a real controller must: power on and brake release take
    their time. Returns the last reply."""
    deadline = time.monotonic() + limit_s
    while True:
        reply = str(d.robotmode())
        if mode in reply or time.monotonic() > deadline:
            return reply
        time.sleep(0.05)


host = sys.argv[1]
d = dashboard_client.DashboardClient(host)
d.connect()
out = {"connected": d.isConnected()}
out["mode_before"] = str(d.robotmode())
d.powerOn()
out["mode_powering"] = str(d.robotmode())
out["mode_powered"] = wait_for_mode(d, "IDLE")
d.brakeRelease()
out["mode_released"] = wait_for_mode(d, "RUNNING")
out["safety_status"] = str(d.safetystatus())
d.loadURP("handeye.urp")
d.play()
out["running_after_play"] = d.running()
out["program_state"] = str(d.programState())
d.stop()
out["running_after_stop"] = d.running()
out["version"] = str(d.polyscopeVersion())
out["remote"] = d.isInRemoteControl()
out["loaded_program"] = str(d.getLoadedProgram())
out["program_state_stopped"] = str(d.programState())
# ur-rtde looks for "True" in a reply controllers give as "true <name>": False on both.
out["program_saved"] = d.isProgramSaved()
d.send("isProgramSaved\n")
out["program_saved_reply"] = d.receive().strip()
out["robot_model"] = str(d.getRobotModel())
out["serial_number"] = str(d.getSerialNumber())
out["safetymode"] = str(d.safetymode())
try:  # nothing plays: the controller answers "Failed to execute: pause", ur-rtde raises it
    d.pause()
    out["pause_when_stopped"] = "no error"
except RuntimeError as e:
    out["pause_when_stopped"] = str(e)
d.disconnect()
print(json.dumps(out))
