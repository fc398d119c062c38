"""A real Orthanc for the viewer's PACS test, as tests/pacs/orthanc_server.h starts it for the
C++ tests: its own configuration, storage and index under a test folder, free ports, the
DICOMweb plugin, HTTP basic authentication, HTTP for loopback clients only; stopped (and
reaped) by stop()."""
import base64
import json
import os
import socket
import subprocess
import time
import urllib.request

ORTHANC = "/usr/sbin/Orthanc"
PLUGIN = "/usr/share/orthanc/plugins/libOrthancDicomWeb.so"


def available():
    return os.path.exists(ORTHANC) and os.path.exists(PLUGIN)


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Orthanc:
    def __init__(self, workdir, user, password):
        self.workdir, self.user, self.password = workdir, user, password
        os.makedirs(workdir, exist_ok=True)
        self.http_port, self.dicom_port = free_port(), free_port()
        config = {
            "Name": "octoray-viewer-test", "StorageDirectory": os.path.join(workdir, "storage"),
            "IndexDirectory": os.path.join(workdir, "index"), "Plugins": [PLUGIN], "LuaScripts": [],
            "HttpPort": self.http_port, "RemoteAccessAllowed": False, "AuthenticationEnabled": True,
            "RegisteredUsers": {user: password}, "OrthancExplorerEnabled": False, "WebDavEnabled": False,
            "DicomServerEnabled": True, "DicomPort": self.dicom_port, "DicomAet": "ORTHANC",
            "DicomCheckCalledAet": False, "DicomAlwaysAllowEcho": True, "DicomAlwaysAllowFind": True,
            "DicomAlwaysAllowGet": True, "SaveJobs": False,
            "DicomWeb": {"Enable": True, "Root": "/dicom-web/", "EnableWado": True,
                         "Host": f"127.0.0.1:{self.http_port}", "Ssl": False},
        }
        path = os.path.join(workdir, "orthanc.json")
        with open(path, "w") as f:
            json.dump(config, f)
        self.log = open(os.path.join(workdir, "orthanc.log"), "w")
        self.process = subprocess.Popen([ORTHANC, "--verbose", path], stdout=self.log, stderr=subprocess.STDOUT,
                                        stdin=subprocess.DEVNULL)
        deadline = time.time() + 30
        while True:
            try:
                self.request("GET", "/system")
                break
            except Exception:
                if self.process.poll() is not None or time.time() > deadline:
                    self.stop()
                    raise RuntimeError(f"Orthanc did not start; see {workdir}/orthanc.log")
                time.sleep(0.1)

    @property
    def url(self):
        return f"http://127.0.0.1:{self.http_port}"

    def request(self, method, path, body=None, content_type=None):
        r = urllib.request.Request(self.url + path, data=body, method=method)
        token = base64.b64encode(f"{self.user}:{self.password}".encode()).decode()
        r.add_header("Authorization", f"Basic {token}")
        if content_type:
            r.add_header("Content-Type", content_type)
        with urllib.request.urlopen(r, timeout=30) as answer:
            return answer.read()

    def upload(self, files):
        for path in files:
            with open(path, "rb") as f:
                self.request("POST", "/instances", f.read(), "application/dicom")

    def stop(self):
        if self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        self.log.close()


class SlowLink:
    """An HTTP relay on 127.0.0.1 in front of a server, holding each WADO-RS instance answer
    back by `delay` seconds: a PACS across a slow network, so that a test can look at the
    viewer while a series is still arriving. Everything else passes unchanged (headers,
    including the client's Authorization; status; body)."""

    def __init__(self, target, delay):
        import http.server
        import threading
        import urllib.error

        link = self

        class Relay(http.server.BaseHTTPRequestHandler):
            protocol_version = "HTTP/1.1"

            def do_GET(self):
                headers = {k: v for k, v in self.headers.items() if k.lower() not in ("host", "connection")}
                req = urllib.request.Request(target + self.path, headers=headers)
                try:
                    with urllib.request.urlopen(req, timeout=60) as r:
                        status, reply, body = r.status, r.headers, r.read()
                except urllib.error.HTTPError as e:
                    status, reply, body = e.code, e.headers, e.read()
                if "/instances/" in self.path:
                    time.sleep(link.delay)
                    link.instances += 1
                self.send_response(status)
                for k, v in reply.items():
                    if k.lower() not in ("content-length", "transfer-encoding", "connection"):
                        self.send_header(k, v)
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                self.wfile.write(body)

            def log_message(self, *args):
                pass

        self.delay, self.instances = delay, 0
        self.server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Relay)
        self.url = f"http://127.0.0.1:{self.server.server_address[1]}"
        self.thread = threading.Thread(target=self.server.serve_forever, daemon=True)
        self.thread.start()

    def stop(self):
        self.server.shutdown()
        self.server.server_close()
