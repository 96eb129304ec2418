"""proden_client: a small client for `proden serve` (docs/api.md), Python 3 standard library only.

Used by the farm integrations (deploy/slurm, deploy/flamenco) and the tests. Import it (copy the
file next to your script or add clients/python to sys.path) or run it as a command:

    python3 proden_client.py --url http://host:8080 [--token-file F] ensure-job JOB.json
    python3 proden_client.py --url ... frame JOB_ID FRAME
    python3 proden_client.py --url ... events [--last-event-id ID]

API (every call raises ProdenError with the HTTP status and the daemon's error code on failure):

    c = Client("http://127.0.0.1:8080", token="...")          # or token_file="..."
    job = c.ensure_job({"name": "shot010", "watch": {...}, "output": {...},
                        "target": {"equivalent_spp": 1024}, "min_passes": 4})
    c.frame(job["id"], 1)                  # GET .../frames/1 -> dict (None with missing_ok)
    for ev in c.events(last_event_id=None):   # SSE, reconnects and resumes with Last-Event-ID
        ...
    c.wait(job["id"], 1, until="converged", timeout=600)   # -> frame dict, or raises Timeout
"""
import http.client
import json
import os
import socket
import sys
import time
import urllib.parse

__all__ = ["Client", "ProdenError", "Timeout", "Event", "parse_until"]


class ProdenError(Exception):
    """An HTTP error answer of the daemon (status, code, message) or a transport failure
    (status 0, code "unreachable")."""

    def __init__(self, status, code, message):
        super().__init__("%s %s: %s" % (status, code, message))
        self.status = status
        self.code = code
        self.message = message


class Timeout(Exception):
    """wait() ran out of time; .frame holds the last frame status seen (or None)."""

    def __init__(self, message, frame=None):
        super().__init__(message)
        self.frame = frame


class Event:
    """One Server-Sent Event: id (int or None), type ("frame", "converged", ...), data (dict)."""

    __slots__ = ("id", "type", "data")

    def __init__(self, id_, type_, data):
        self.id, self.type, self.data = id_, type_, data

    def __repr__(self):
        return "Event(%r, %r, %r)" % (self.id, self.type, self.data)


def parse_until(until):
    """'converged' -> ("converged", None); 'version>K' -> ("version", K). Raises ValueError."""
    if until == "converged":
        return ("converged", None)
    if until.startswith("version>"):
        k = until[len("version>"):]
        if k.isdigit():
            return ("version", int(k))
    raise ValueError("until must be 'converged' or 'version>K' (K a non-negative integer), got %r"
                     % until)


def condition_met(frame, cond):
    """True when a frame status dict satisfies a parse_until() condition."""
    kind, k = cond
    if frame is None:
        return False
    if kind == "converged":
        return bool(frame.get("converged"))
    return int(frame.get("version", 0)) > k


class Client:
    def __init__(self, url, token=None, token_file=None, timeout=30.0):
        u = urllib.parse.urlsplit(url)
        if u.scheme not in ("http", "https") or not u.hostname:
            raise ValueError("url must be http(s)://host[:port], got %r" % url)
        self.scheme = u.scheme
        self.host = u.hostname
        self.port = u.port or (443 if u.scheme == "https" else 80)
        self.prefix = u.path.rstrip("/")
        if token_file and not token:
            with open(token_file) as f:
                token = f.read().strip()
        self.token = token
        self.timeout = timeout

    # ---- transport ----
    def _conn(self, timeout):
        cls = http.client.HTTPSConnection if self.scheme == "https" else http.client.HTTPConnection
        return cls(self.host, self.port, timeout=timeout)

    def request(self, method, path, body=None, headers=None, timeout=None):
        """Returns (status, headers dict with lower-case keys, body bytes); raises ProdenError
        (status 0) when the daemon cannot be reached."""
        h = dict(headers or {})
        if self.token:
            h.setdefault("Authorization", "Bearer " + self.token)
        if isinstance(body, (dict, list)):
            body = json.dumps(body).encode()
            h.setdefault("Content-Type", "application/json")
        conn = self._conn(timeout or self.timeout)
        try:
            conn.request(method, self.prefix + path, body=body, headers=h)
            r = conn.getresponse()
            return r.status, {k.lower(): v for k, v in r.getheaders()}, r.read()
        except (OSError, http.client.HTTPException) as e:
            raise ProdenError(0, "unreachable", "%s %s: %s" % (method, path, e)) from e
        finally:
            conn.close()

    def call(self, method, path, body=None, ok=(200,), **kw):
        """A JSON request; returns the parsed answer (None for an empty body)."""
        status, _, data = self.request(method, path, body, **kw)
        if status not in ok:
            code, message = "http_%d" % status, data.decode(errors="replace")[:500]
            try:
                err = json.loads(data)["error"]
                code, message = err["code"], err["message"]
            except (ValueError, KeyError, TypeError):
                pass
            raise ProdenError(status, code, message)
        return json.loads(data) if data else None

    # ---- jobs ----
    def jobs(self):
        return self.call("GET", "/api/v1/jobs")["jobs"]

    def job(self, job_id):
        return self.call("GET", "/api/v1/jobs/" + _q(job_id))

    def create_job(self, spec):
        return self.call("POST", "/api/v1/jobs", spec, ok=(201,))

    def ensure_job(self, spec):
        """Creates the job, or returns the existing job of that name (a re-run farm task must not
        fail on 409). Raises ProdenError 409 if the existing job watches another directory."""
        try:
            return self.create_job(spec)
        except ProdenError as e:
            if e.status != 409:
                raise
        for j in self.jobs():
            if j["name"] == spec["name"]:
                want = (spec.get("watch") or {}).get("dir")
                have = (j.get("watch") or {}).get("dir")
                if want and have and os.path.realpath(want) != os.path.realpath(have):
                    raise ProdenError(409, "conflict", "job %s exists and watches %s, not %s"
                                      % (spec["name"], have, want))
                return j
        raise ProdenError(409, "conflict", "job %s exists but is not listed" % spec["name"])

    def delete_job(self, job_id):
        self.call("DELETE", "/api/v1/jobs/" + _q(job_id), ok=(204,))

    def pause(self, job_id):
        return self.call("POST", "/api/v1/jobs/%s/pause" % _q(job_id))

    def resume(self, job_id):
        return self.call("POST", "/api/v1/jobs/%s/resume" % _q(job_id))

    # ---- frames ----
    def frames(self, job_id):
        return self.call("GET", "/api/v1/jobs/%s/frames" % _q(job_id))["frames"]

    def frame(self, job_id, frame, missing_ok=False):
        """GET .../frames/N. With missing_ok, a frame without any pass yet is None (the job must
        exist: a missing job still raises 404)."""
        try:
            return self.call("GET", "/api/v1/jobs/%s/frames/%d" % (_q(job_id), int(frame)))
        except ProdenError as e:
            if missing_ok and e.status == 404 and "no frame" in e.message:
                return None
            raise

    def history(self, job_id, frame):
        """GET .../frames/N/history: every version the frame published, oldest first (each with
        its estimated_error and converged). The images kept are the frame's `versions`."""
        return self.call("GET", "/api/v1/jobs/%s/frames/%d/history"
                         % (_q(job_id), int(frame)))["versions"]

    def image(self, job_id, frame, fmt="exr", layer=None, version=None):
        """The published image (bytes) of a frame: the latest version, or `version`."""
        q = {"format": fmt}
        if layer:
            q["layer"] = layer
        if version is not None:
            q["version"] = str(int(version))
        path = "/api/v1/jobs/%s/frames/%d/image?%s" % (_q(job_id), int(frame),
                                                       urllib.parse.urlencode(q))
        status, _, data = self.request("GET", path)
        if status != 200:
            try:
                err = json.loads(data)["error"]
                raise ProdenError(status, err["code"], err["message"])
            except (ValueError, KeyError, TypeError):
                raise ProdenError(status, "http_%d" % status, data[:200].decode(errors="replace"))
        return data

    def upload_pass(self, job_id, frame, pass_name, path):
        """PUT a pass: {"status": "queued"} (202), or "ingested" (200) when the same bytes were
        uploaded and accumulated before (idempotent); other bytes for the pass raise 409."""
        with open(path, "rb") as f:
            body = f.read()
        return self.call("PUT", "/api/v1/jobs/%s/frames/%d/passes/%s"
                         % (_q(job_id), int(frame), _q(pass_name)), body, ok=(200, 202),
                         headers={"Content-Type": "application/octet-stream"})

    # ---- events ----
    def events(self, last_event_id=None, timeout=None, reconnect=True, idle_timeout=60.0):
        """Yields Events from GET /api/v1/events. On a dropped connection it reconnects with
        Last-Event-ID = the last id seen (so nothing is missed while the daemon keeps it in its
        history) until `timeout` seconds have passed in all (None: forever); then it returns.
        `idle_timeout` bounds one read (the daemon sends keep-alive comments meanwhile)."""
        deadline = None if timeout is None else time.monotonic() + timeout
        last = last_event_id
        backoff = 0.2
        while True:
            remaining = None if deadline is None else deadline - time.monotonic()
            if remaining is not None and remaining <= 0:
                return
            try:
                read_timeout = idle_timeout if remaining is None else min(idle_timeout, remaining)
                for ev in self._stream(last, read_timeout, deadline):
                    backoff = 0.2
                    if ev.id is not None:
                        last = ev.id
                    yield ev
                if deadline is not None and time.monotonic() >= deadline:
                    return
            except (OSError, http.client.HTTPException, ProdenError) as e:
                if isinstance(e, ProdenError) and e.status not in (0, 503):
                    raise
                if not reconnect:
                    raise
            if not reconnect:
                return
            time.sleep(backoff)
            backoff = min(backoff * 2, 5.0)

    def _stream(self, last_id, read_timeout, deadline):
        conn = self._conn(read_timeout)
        h = {"Accept": "text/event-stream"}
        if self.token:
            h["Authorization"] = "Bearer " + self.token
        if last_id is not None:
            h["Last-Event-ID"] = str(last_id)
        try:
            conn.request("GET", self.prefix + "/api/v1/events", headers=h)
            r = conn.getresponse()
            if r.status != 200:
                raise ProdenError(r.status, "http_%d" % r.status, r.read()[:200].decode())
            fields = {}
            data = []
            while True:
                if deadline is not None:
                    left = deadline - time.monotonic()
                    if left <= 0:
                        return
                    if conn.sock is not None:  # keep-alive comments must not outlive the deadline
                        conn.sock.settimeout(min(read_timeout, left))
                try:
                    line = r.readline()
                except socket.timeout:
                    if deadline is not None and time.monotonic() >= deadline:
                        return
                    raise  # silent longer than the keep-alive interval: reconnect
                if not line:
                    return  # closed by the daemon (restart, slow client): the caller resumes
                line = line.decode("utf-8", "replace").rstrip("\r\n")
                if line == "":
                    if data or "event" in fields:
                        try:
                            payload = json.loads("\n".join(data)) if data else None
                        except ValueError:
                            payload = "\n".join(data)
                        eid = fields.get("id")
                        yield Event(int(eid) if eid and eid.isdigit() else None,
                                    fields.get("event", "message"), payload)
                    fields, data = {}, []
                    continue
                if line.startswith(":"):
                    continue  # keep-alive comment
                k, _, v = line.partition(":")
                v = v[1:] if v.startswith(" ") else v
                if k == "data":
                    data.append(v)
                elif k in ("id", "event"):
                    fields[k] = v
        finally:
            conn.close()

    # ---- waiting ----
    def wait(self, job_id, frame, until="converged", timeout=600.0, on_event=None):
        """Blocks until frame `frame` of job `job_id` satisfies `until` ('converged' or
        'version>K'); returns its status dict. Follows SSE (resuming across daemon restarts) and
        re-reads the frame after each event of that frame; raises Timeout (with the last status)
        or ProdenError 404 if the job does not exist."""
        cond = parse_until(until)
        deadline = time.monotonic() + timeout
        last_id = None
        status = None
        while True:
            try:
                status = self.frame(job_id, frame, missing_ok=True)
            except ProdenError as e:
                if e.status != 0:
                    raise
            if condition_met(status, cond):
                return status
            left = deadline - time.monotonic()
            if left <= 0:
                raise Timeout("frame %s of job %s: %s not reached in %.0f s"
                              % (frame, job_id, until, timeout), status)
            # Follow events until one concerns this frame, then re-read the status (the status is
            # the truth; events only say when to look). The first read of the history after
            # last_id=None replays old events, which only costs an extra GET.
            try:
                for ev in self.events(last_event_id=last_id, timeout=min(left, 30.0)):
                    last_id = ev.id if ev.id is not None else last_id
                    if on_event:
                        on_event(ev)
                    d = ev.data if isinstance(ev.data, dict) else {}
                    if d.get("job") == job_id and d.get("frame") == int(frame):
                        break
                    if ev.type == "job" and d.get("job") == job_id and d.get("state") == "deleted":
                        raise ProdenError(404, "not_found", "job %s was deleted" % job_id)
            except ProdenError as e:
                if e.status not in (0, 503):
                    raise
                time.sleep(0.5)


def _q(s):
    return urllib.parse.quote(str(s), safe="")


# ---- command line -----------------------------------------------------------------------------

def main(argv=None):
    import argparse
    p = argparse.ArgumentParser(prog="proden_client.py", description=__doc__.split("\n")[0])
    p.add_argument("--url", default=os.environ.get("PRODEN_URL", "http://127.0.0.1:8080"))
    p.add_argument("--token-file", default=os.environ.get("PRODEN_TOKEN_FILE"))
    sub = p.add_subparsers(dest="cmd", required=True)
    e = sub.add_parser("ensure-job", help="create a job unless one of that name exists (a re-run "
                       "registration task succeeds); prints the job")
    e.add_argument("spec", help="a JSON file, '-' for stdin, or the JSON object itself")
    f = sub.add_parser("frame", help="print a frame's status (exit 3 if it has no pass yet)")
    f.add_argument("job")
    f.add_argument("frame", type=int)
    v = sub.add_parser("events", help="print events as JSON lines")
    v.add_argument("--last-event-id", type=int)
    v.add_argument("--timeout", type=float)
    a = p.parse_args(argv)
    c = Client(a.url, token_file=a.token_file)
    try:
        if a.cmd == "ensure-job":
            if a.spec.lstrip().startswith("{"):
                spec = json.loads(a.spec)
            elif a.spec == "-":
                spec = json.load(sys.stdin)
            else:
                with open(a.spec) as fh:
                    spec = json.load(fh)
            print(json.dumps(c.ensure_job(spec)))
        elif a.cmd == "frame":
            fr = c.frame(a.job, a.frame, missing_ok=True)
            if fr is None:
                print("frame %d of job %s has no pass yet" % (a.frame, a.job), file=sys.stderr)
                return 3
            print(json.dumps(fr))
        elif a.cmd == "events":
            for ev in c.events(last_event_id=a.last_event_id, timeout=a.timeout):
                print(json.dumps({"id": ev.id, "event": ev.type, "data": ev.data}), flush=True)
    except ProdenError as err:
        print("proden_client: %s" % err, file=sys.stderr)
        return 1 if err.status == 0 else 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
