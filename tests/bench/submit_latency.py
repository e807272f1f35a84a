#!/usr/bin/env python3
"""How long the coordinator keeps other clients waiting while it takes a huge job.

Starts a prism-coordinator on loopback with a fresh data directory, submits a 16384x16384,
4-bin, 1-spp job (262,144 tasks) with `prism submit`, and runs `prism jobs` every 50 ms until
the submission returns; prints the submission's time and the slowest and median `prism jobs`.

    python3 tests/bench/submit_latency.py [--build build] [--scene scenes/glass-enclosed.pbrt]
"""
import argparse
import os
import re
import shutil
import subprocess
import tempfile
import time

parser = argparse.ArgumentParser()
parser.add_argument("--build", default="build")
parser.add_argument("--scene", default="scenes/glass-enclosed.pbrt")
parser.add_argument("--resolution", default="16384x16384")
args = parser.parse_args()

data = tempfile.mkdtemp(prefix="prism-submit-latency-")
env = dict(os.environ, PRISM_API_TOKEN="bench", PRISM_WORKER_SECRET="bench")
coordinator = subprocess.Popen(
    [os.path.join(args.build, "coordinator/prism-coordinator"), "--listen", "127.0.0.1:0",
     "--data-dir", data],
    env=env, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
try:
    port = None
    for line in coordinator.stdout:
        found = re.search(r"listening on port (\d+)", line)
        if found:
            port = found.group(1)
            break
    env["PRISM_COORDINATOR"] = "127.0.0.1:" + port
    prism = os.path.join(args.build, "client/prism")
    start = time.time()
    submit = subprocess.Popen(
        [prism, "submit", args.scene, "--resolution", args.resolution, "--spp", "1",
         "--integrator", "uniform", "--bins", "4", "--no-prepass"],
        env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    waits = []
    while submit.poll() is None:
        asked = time.time()
        subprocess.run([prism, "jobs"], env=env, capture_output=True)
        waits.append((asked - start, time.time() - asked))
        time.sleep(0.05)
    print("submit: %.2f s, exit %d" % (time.time() - start, submit.returncode))
    durations = sorted(w for _, w in waits)
    print("prism jobs during it: %d calls, median %.3f s, slowest %.3f s (asked at %.2f s)" %
          (len(waits), durations[len(durations) // 2], durations[-1],
           max(waits, key=lambda w: w[1])[0]))
finally:
    coordinator.terminate()
    coordinator.wait()
    shutil.rmtree(data, ignore_errors=True)
