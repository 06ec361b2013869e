#!/usr/bin/python3
"""rviz loads config/rviz/nerfslam.rviz without errors, on a virtual display (Xvfb).

Starts its own roscore on a free port of 127.0.0.1, runs `xvfb-run rviz -d CONFIG` against it and
passes when
  - rviz subscribes, within the time limit, to every topic the config names (its displays' `Topic:`
    entries, plus /tf and /tf_static): each display was created from its class and started, and
  - rviz printed no error ([ERROR] lines: a display class that cannot be loaded, a config that does
    not parse) and is still running.
Debian's rviz asks rospack for a `media_export` package that Debian does not ship and prints
"[rospack] Error: no such package media_export" at start-up, whatever the config: that line is
reported but not counted.

  rviz_config_test.py CONFIG [TIMEOUT_S]
"""
import os
import re
import signal
import socket
import subprocess
import sys
import tempfile
import time

import rosgraph

IGNORED = [re.compile(r"\[rospack\] Error: no such package media_export")]
ERROR = re.compile(r"\[\s*ERROR\]|\[rospack\] Error|Error parsing|could not be loaded", re.IGNORECASE)


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def config_topics(path):
    topics = set()
    with open(path) as f:
        for line in f:
            m = re.match(r"\s*(?:Image |Marker )?Topic:\s*(/\S+)\s*$", line)
            if m:
                topics.add(m.group(1))
    return topics | {"/tf", "/tf_static"}


def rviz_subscriptions(master):
    try:
        _, subscribers, _ = master.getSystemState()
    except Exception:  # master not up yet
        return set()
    return {topic for topic, nodes in subscribers if any(n.startswith("/rviz") for n in nodes)}


def stop(proc, sig=signal.SIGINT, wait=10):
    if proc.poll() is not None:
        return
    try:
        os.killpg(proc.pid, sig)
        proc.wait(wait)
    except (subprocess.TimeoutExpired, ProcessLookupError):
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        proc.wait()


def main():
    if len(sys.argv) < 2:
        print(__doc__)
        return 2
    config = sys.argv[1]
    timeout = float(sys.argv[2]) if len(sys.argv) > 2 else 120.0
    if not os.path.isfile(config):
        print(f"FAIL: rviz config {config} not found")
        return 1
    wanted = config_topics(config)
    print(f"{config}: {len(wanted)} topics: {' '.join(sorted(wanted))}")

    tmp = tempfile.mkdtemp(prefix="nerfslam_rviz_")
    port = free_port()
    env = dict(os.environ, ROS_MASTER_URI=f"http://127.0.0.1:{port}", ROS_IP="127.0.0.1",
               ROS_HOME=tmp, ROS_LOG_DIR=os.path.join(tmp, "log"), HOME=tmp)
    env.pop("ROS_HOSTNAME", None)
    os.environ.update(ROS_MASTER_URI=env["ROS_MASTER_URI"], ROS_IP="127.0.0.1")
    core = subprocess.Popen(["roscore", "-p", str(port)], env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.STDOUT, start_new_session=True)
    rviz = None
    log_path = os.path.join(tmp, "rviz.log")
    try:
        master = rosgraph.Master("/rviz_config_test", master_uri=env["ROS_MASTER_URI"])
        t0 = time.time()
        while not master.is_online():
            if time.time() - t0 > 60 or core.poll() is not None:
                print("FAIL: roscore did not start")
                return 1
            time.sleep(0.2)
        with open(log_path, "w") as log:
            rviz = subprocess.Popen(["xvfb-run", "-a", "-s", "-screen 0 1280x1024x24", "rviz", "-d", config],
                                    env=env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
        t0 = time.time()
        got = set()
        while time.time() - t0 < timeout and rviz.poll() is None:
            got = rviz_subscriptions(master) & wanted
            if got == wanted:
                break
            time.sleep(0.5)
        elapsed = time.time() - t0
        # A little longer for errors printed after the last subscription.
        time.sleep(2.0)
        alive = rviz.poll() is None
        stop(rviz)
        with open(log_path) as f:
            lines = f.read().splitlines()
        ignored = [l for l in lines if any(p.search(l) for p in IGNORED)]
        errors = [l for l in lines if ERROR.search(l) and l not in ignored]
        for l in ignored:
            print(f"(not counted: {l.strip()})")
        ok = True
        if got != wanted:
            print(f"FAIL: after {elapsed:.0f} s rviz subscribes to {len(got)}/{len(wanted)} topics; "
                  f"missing: {' '.join(sorted(wanted - got))}")
            ok = False
        else:
            print(f"rviz subscribed to all {len(wanted)} topics after {elapsed:.1f} s")
        if not alive:
            print(f"FAIL: rviz exited (code {rviz.returncode}) before the check ended")
            ok = False
        if errors:
            print(f"FAIL: rviz printed {len(errors)} error line(s):")
            for l in errors:
                print("  " + l)
            ok = False
        if not ok:
            print("--- rviz output:")
            print("\n".join(lines[-40:]))
        return 0 if ok else 1
    finally:
        if rviz is not None:
            stop(rviz)
        stop(core)


if __name__ == "__main__":
    sys.exit(main())
