#!/usr/bin/python3
"""How soon octoray-view shows a series it retrieves from a PACS (issue 13).

A real Orthanc on loopback (tests/viewer/orthanc.py) holds the 140-slice Philips 1 mm head of
../shared; a relay in front of it (SlowLink) holds each WADO-RS instance back DELAY seconds,
as a slower network would. octoray-view, scripted under Xvfb, retrieves the series through the
PACS panel's action; the script dumps its state when the first slice is shown, when every slice
is shown (the last instance has arrived: before this change, the earliest moment anything could
be shown), and when the store is built and every view has converged. The times are the state
files' modification times, from the moment the retrieval was asked for.

Usage: bench/pacs_progressive.py BUILD_DIR DELAY_S RUNS
"""
import json
import os
import statistics
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "../tests/viewer"))
import orthanc  # noqa: E402
import pydicom  # noqa: E402

BUILD, DELAY, RUNS = sys.argv[1], float(sys.argv[2]), int(sys.argv[3])
SHARED = os.environ.get("OCTORAY_SHARED", os.path.join(HERE, "../../shared"))
HEAD = os.path.join(SHARED, "data/dicom/dcm_qa_ct/Philips/S21570/S2020")
files = sorted(os.path.join(HEAD, n) for n in os.listdir(HEAD) if n != "DIRFILE")
first = pydicom.dcmread(files[0], stop_before_pixels=True)
rows = []
for run in range(RUNS):
    work = tempfile.mkdtemp(prefix="octoray-bench-pacs-")
    path = lambda name: os.path.join(work, name)  # noqa: E731
    server = orthanc.Orthanc(path("orthanc"), "octoray", "bench-" + os.urandom(6).hex())
    server.upload(files)
    link = orthanc.SlowLink(server.url, DELAY)
    with open(path("cred"), "w") as f:
        f.write(f"basic octoray:{server.password}\n")
    os.chmod(path("cred"), 0o600)
    steps = [
        {"type": "action", "name": "pacs-server", "value": {"url": link.url + "/dicom-web", "credentials": path("cred")}},
        {"type": "dump-state", "path": path("asked.json")},
        {"type": "action", "name": "pacs-retrieve", "wait": 0,
         "value": {"study": str(first.StudyInstanceUID), "series": str(first.SeriesInstanceUID)}},
        {"type": "wait-preview", "fraction": 1 / 140, "timeout": 600, "wait": 0},
        {"type": "dump-state", "path": path("first.json"), "wait": 0},
        {"type": "wait-preview", "fraction": 1.0, "timeout": 600, "wait": 0},
        {"type": "dump-state", "path": path("all.json"), "wait": 0},
        {"type": "wait-converged", "timeout": 900},
        {"type": "dump-state", "path": path("ready.json")},
        {"type": "quit"},
    ]
    with open(path("script.json"), "w") as f:
        json.dump({"format": "octoray-view-script", "version": 1, "events": steps}, f)
    env = dict(os.environ, OCTORAY_CONFIG=path("config"), NO_PROXY="127.0.0.1,localhost")
    p = subprocess.run(["xvfb-run", "-a", "-s", "-screen 0 1280x800x24 -noreset", os.path.join(BUILD, "bin/octoray-view"),
                        "--script", path("script.json"), "--exit", "--size", "1280x800", "--cache-dir", path("cache")],
                       env=env, capture_output=True, text=True)
    link.stop()
    server.stop()
    if p.returncode != 0:
        sys.exit(f"octoray-view failed ({p.returncode}): {p.stderr[-2000:]}")
    t0 = os.path.getmtime(path("asked.json"))
    t = [os.path.getmtime(path(n)) - t0 for n in ("first.json", "all.json", "ready.json")]
    rows.append(t)
    print(f"run {run + 1}: first slice {t[0]:.2f} s, every slice {t[1]:.2f} s, store built and views converged {t[2]:.2f} s",
          flush=True)
names = ["first slice shown", "every slice shown (= retrieval complete: the old first picture)",
         "store built, views converged"]
for i, name in enumerate(names):
    print(f"median {name}: {statistics.median(r[i] for r in rows):.2f} s")
