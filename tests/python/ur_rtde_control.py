"""ur-rtde (SDU ur_rtde) RTDEControlInterface drives the simulated controller, as a team's
motion code would in CI; RTDEReceiveInterface reads where the arm went.

Usage: ur_rtde_control.py HOST. Prints one JSON line per step to stdout; the Rust test
(tests/e2e/ur_clients.rs) checks the values against the simulator's own state. Where the test
must act on the simulator (arm a protective stop, move the speed slider) this script prints
{"event": NAME} and waits for a line on stdin."""
import json
import sys
import time

import dashboard_client
import rtde_control
import rtde_receive

host = sys.argv[1]


def emit(step, **values):
    print(json.dumps({"step": step, **values}), flush=True)


def ask(event):
    """Ask the Rust test to act on the simulator, wait until it has."""
    print(json.dumps({"event": event}), flush=True)
    answer = sys.stdin.readline().strip()
    if answer != "ok":
        raise RuntimeError(f"test harness answered {answer!r} to {event}")


def settle(r):
    """Lets the receive interface catch up, so a value read afterwards was sampled after the
    call returned: 20 ms, and at least 20 ms of controller time beyond the sample seen now (on
    a loaded machine the receive thread can lag behind the controller)."""
    t0 = r.getTimestamp()
    time.sleep(0.02)
    deadline = time.monotonic() + 2.0
    while r.getTimestamp() < t0 + 0.02 and time.monotonic() < deadline:
        time.sleep(0.005)


def wait_running(c, limit=5.0):
    """reuploadScript only sends the program; wait until the controller runs it."""
    deadline = time.monotonic() + limit
    while not c.isProgramRunning() and time.monotonic() < deadline:
        time.sleep(0.01)
    return c.isProgramRunning()


def timed(f, *args):
    t = time.monotonic()
    result = f(*args)
    return result, time.monotonic() - t


t = time.monotonic()
c = rtde_control.RTDEControlInterface(host)
r = rtde_receive.RTDEReceiveInterface(host)
emit("connect", seconds=time.monotonic() - t, running=c.isProgramRunning(), connected=c.isConnected())

q0 = r.getActualQ()
target = [a + d for a, d in zip(q0, [0.3, -0.2, 0.25, -0.1, 0.2, 0.3])]
ok, secs = timed(c.moveJ, target, 1.05, 1.4)
settle(r)
emit("moveJ", ok=ok, seconds=secs, target=target, q=r.getActualQ())

p = r.getActualTCPPose()
p1 = list(p)
p1[0] += 0.03
p1[2] -= 0.05
ok, secs = timed(c.moveL, p1, 0.25, 1.2)
settle(r)
emit("moveL", ok=ok, seconds=secs, target=p1, pose=r.getActualTCPPose(), q=r.getActualQ())

p2 = list(p1)
p2[2] += 0.08
ok, secs = timed(c.moveL, p2, 0.1, 0.5, True)
progress, z_while_running = [], []
deadline = time.monotonic() + 10
while time.monotonic() < deadline:
    value = c.getAsyncOperationProgress()
    progress.append(value)
    if value < 0:
        break
    z_while_running.append(r.getActualTCPPose()[2])
    time.sleep(0.02)
settle(r)
emit("moveL_async", ok=ok, seconds=secs, target=p2, progress=progress,
     z_while_running=z_while_running, pose=r.getActualTCPPose())

tcp = [0.0, 0.0, 0.12, 0.0, 0.0, 0.3]
ok = c.setTcp(tcp)
settle(r)
emit("setTcp", ok=ok, offset=c.getTCPOffset(), q=r.getActualQ(), pose=r.getActualTCPPose(),
     fk=c.getForwardKinematics(), ik=c.getInverseKinematics(r.getActualTCPPose()))

# The other motion and kinematics calls of the control program.
home = r.getActualQ()
pose = r.getActualTCPPose()
goal = list(pose)
goal[1] += 0.04
ok = c.moveJ_IK(goal, 1.0, 1.4)
settle(r)
steps = {"moveJ_IK": [ok, r.getActualTCPPose(), goal]}
fk_q = [a + d for a, d in zip(home, [0.1, -0.05, 0.05, 0.0, 0.1, 0.0])]
ok = c.moveL_FK(fk_q, 0.25, 1.2)
settle(r)
steps["moveL_FK"] = [ok, r.getActualQ(), fk_q]
ok_speed = c.speedL([0.0, 0.0, 0.02, 0.0, 0.0, 0.0], 0.5, 0.0)
z0 = r.getActualTCPPose()[2]
time.sleep(0.5)
tcp_speed = r.getActualTCPSpeed()
ok_stop = c.speedStop(1.0)
settle(r)
steps["speedL"] = [ok_speed and ok_stop, tcp_speed, r.getActualTCPPose()[2] - z0]
start = r.getActualQ()
servo_target = list(start)
for i in range(100):
    t0 = c.initPeriod()
    servo_target[5] = start[5] + 0.002 * (i + 1)
    c.servoJ(servo_target, 0.0, 0.0, 0.008, 0.1, 300)
    c.waitPeriod(t0)
time.sleep(0.05)
ok = c.servoStop(2.0)
settle(r)
steps["servoJ"] = [ok, r.getActualQ()[5] - start[5]]
far = list(start)
far[0] += 1.0
ok_async = c.moveJ(far, 0.5, 1.0, True)
time.sleep(0.4)
c.stopJ(2.0, False)
settle(r)
q_stop = r.getActualQ()
steps["stopJ"] = [ok_async, q_stop[0] - start[0], c.getAsyncOperationProgress(), r.getActualQd()]
ok = c.setPayload(1.5, [0.0, 0.01, 0.05])
settle(r)
steps["setPayload"] = [ok, r.getPayload(), r.getPayloadCog()]
# getActualToolFlangePose and getStepTime are real-time commands for the client: it reads the answer registers
# before the program has written them, so the first call returns what was there (also on a
# controller); asked again a few cycles later it answers.
pose_trans = c.poseTrans([0.1, 0, 0, 0, 0, 0], [0, 0.2, 0, 0, 0, 0])
c.getActualToolFlangePose()
time.sleep(0.05)
flange = c.getActualToolFlangePose()
c.getStepTime()  # real-time as well
time.sleep(0.05)
step_time = c.getStepTime()
steps["queries"] = {
    "steady": c.isSteady(),
    "joints_ok": c.isJointsWithinSafetyLimits(r.getActualQ()),
    "joints_out": c.isJointsWithinSafetyLimits([7.0, 0, 0, 0, 0, 0]),
    "ik_has_solution": c.getInverseKinematicsHasSolution(r.getActualTCPPose()),
    "ik_no_solution": c.getInverseKinematicsHasSolution([3.0, 0, 0, 0, 0, 0]),
    "pose_trans": pose_trans,
    "flange": flange,
    "q": r.getActualQ(),
    "step_time": step_time,
}
# stopL during an asynchronous moveL; the target waypoint; payload with inertia; IK near a
# given joint set with the client's default tolerances; pose limits.
start_pose = r.getActualTCPPose()
far_pose = list(start_pose)
far_pose[2] += 0.15
ok_async = c.moveL(far_pose, 0.1, 0.5, True)
time.sleep(0.4)
waypoint = c.getTargetWaypoint()
c.stopL(2.0)
settle(r)
steps["stopL"] = [ok_async, r.getActualTCPPose()[2] - start_pose[2], r.getActualTCPSpeed(),
                  c.getAsyncOperationProgress(), waypoint, far_pose]
ok = c.setTargetPayload(2.0, [0.0, 0.0, 0.1], [0.01, 0.01, 0.02, 0.0, 0.0, 0.0])
# The receive interface's sample may predate the command's reply: read after a fresh one.
settle(r)
steps["setTargetPayload"] = [ok, r.getPayload(), r.getPayloadCog(), r.getPayloadInertia()]
q_now = r.getActualQ()
steps["ik_near"] = [c.getInverseKinematics(r.getActualTCPPose(), q_now), q_now]
steps["pose_limits"] = [c.isPoseWithinSafetyLimits(r.getActualTCPPose()),
                        c.isPoseWithinSafetyLimits([3.0, 0.0, 0.0, 0.0, 0.0, 0.0])]
emit("more_calls", **steps)

q_before = r.getActualQ()
ok = c.speedJ([0.15, 0.0, 0.0, 0.0, 0.0, -0.1], 0.8, 0.0)
time.sleep(0.8)
qd_running = r.getActualQd()
stopped = c.speedStop(2.0)
settle(r)
emit("speedJ", ok=ok, stopped=stopped, qd_running=qd_running, qd_after=r.getActualQd(),
     q_before=q_before, q_after=r.getActualQ())

# The speed slider at 50 % doubles a move's duration.
start = r.getActualQ()
there = [a + d for a, d in zip(start, [0.3, 0.0, 0.0, 0.0, 0.0, 0.0])]
ok_full, secs_full = timed(c.moveJ, there, 1.0, 1.0)
ask("slider_half")
ok_half, secs_half = timed(c.moveJ, start, 1.0, 1.0)
ask("slider_full")
emit("slider", ok=[ok_full, ok_half], seconds_full=secs_full, seconds_half=secs_half)

# A protective stop half way through a synchronous move: moveJ returns False.
start = r.getActualQ()
far = [a + d for a, d in zip(start, [-0.5, 0.2, -0.2, 0.0, 0.3, -0.4])]
ask("arm_protective_stop")
ok, secs = timed(c.moveJ, far, 0.5, 1.0)
settle(r)
emit("protective_stop", ok=ok, seconds=secs, start=start, target=far, q=r.getActualQ(),
     safety_mode=r.getSafetyMode(), protective_stopped=r.isProtectiveStopped(),
     running=c.isProgramRunning())

db = dashboard_client.DashboardClient(host)
db.connect()
db.unlockProtectiveStop()
time.sleep(0.1)
db.disconnect()
settle(r)
safety_after_unlock = r.getSafetyMode()
reuploaded = c.reuploadScript()
emit("recover", safety_mode=safety_after_unlock, reuploaded=reuploaded, running=wait_running(c))

c.stopScript()
running_after_stop = c.isProgramRunning()
c.disconnect()
emit("stopScript", running=running_after_stop, connected=c.isConnected())

reconnected = c.reconnect()
ok = c.moveJ(q0, 1.05, 1.4)
settle(r)
emit("reconnect", reconnected=reconnected, running=c.isProgramRunning(), ok=ok, target=q0,
     q=r.getActualQ())

# The RTDE watchdog: kicked, the program runs on; not kicked, it stops.
ok = c.setWatchdog(5.0)
for _ in range(12):
    c.kickWatchdog()
    time.sleep(0.05)
running_kicked = c.isProgramRunning()
time.sleep(0.5)
emit("watchdog", ok=ok, running_kicked=running_kicked, running_unkicked=c.isProgramRunning())

# A command the simulator does not model: the call returns False at once, it does not hang.
c.reuploadScript()
running_before = wait_running(c)
ok, secs = timed(c.teachMode)
emit("unsupported", running_before=running_before, ok=ok, seconds=secs,
     running=c.isProgramRunning())
c.disconnect()

# The upper register range (registers 24-47; the lower range free for a fieldbus).
RTDEControl = rtde_control.RTDEControlInterface
upper = RTDEControl(host, -1.0, RTDEControl.FLAG_UPLOAD_SCRIPT | RTDEControl.FLAG_UPPER_RANGE_REGISTERS)
q = r.getActualQ()
target = [a + d for a, d in zip(q, [-0.2, 0.1, 0.0, 0.0, 0.0, 0.1])]
ok = upper.moveJ(target, 1.05, 1.4)
settle(r)
ok_tcp = upper.setTcp([0.0, 0.0, 0.05, 0.0, 0.0, 0.0])
emit("upper_range", ok=[ok, ok_tcp], target=target, q=r.getActualQ(), offset=upper.getTCPOffset())
upper.stopScript()
upper.disconnect()
r.disconnect()
emit("done")
