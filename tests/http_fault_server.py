#!/usr/bin/env python3
"""http_fault_server.py - a small HTTP/1.1 file server that injects faults
into payload range requests, for tests/test_http.sh (python3 standard
library only).

Serves the files under ROOT with single range requests (206 with
Content-Range; 416 with 'bytes */SIZE' for a range past the end), a strong
ETag and Last-Modified, If-Range (a validator that does not match: 200 with
the whole file), keep-alive connections, GET and HEAD.

The first folder of a URL names the fault its payload requests get:
/416/city.hlod, /truncate/city.hlod, /reset/city.hlod and /stall/city.hlod serve ROOT/city.hlod
with that fault (/416-2/city.hlod too: anything after a '-' names a run
counted apart, so a test can run a kind again; a name eN or eNmK, as in
/stall-e1m6/, also sets that run's --every to N and its --max to K), any
other path without faults.  Faults hit payload requests
only: a range starting at or after the 256-byte store header, outside the
node table and before the extras table (whose places the server reads from
the store's header), so the reads at open are always answered.  Every Nth payload
request (--every N, counted for each such folder apart) gets:
  416       a 416 (range not satisfiable) with 'Content-Range: bytes */SIZE'
            (the file's true size, as a server or proxy glitch would send);
  truncate  a 206 whose Content-Length is the range's, then half the body,
            then an orderly close (FIN): a truncated body;
  reset     an abrupt reset (SO_LINGER 0, close: RST), alternately right
            after the request and after the headers and half the body;
  stall     a 206 whose Content-Length is the range's, then half the body,
            then nothing: the connection is held open until the client
            drops it (or 60 s), as a server that hangs mid-transfer.
Faults stop after --max K of them, and --for S seconds after the first
payload request, whichever comes first (for each folder apart).  Each fault is
one line in --log (flushed at once): 'fault N KIND bytes=A-B at T' (T: Unix
time in ms).  The port (--port 0: any free one) is written to --port-file
once listening.
"""
import argparse
import email.utils
import http.server
import os
import re
import socket
import socketserver
import struct
import sys
import threading
import time

HEADER_SIZE = 256
KINDS = ("416", "truncate", "reset", "stall")
STALL_S = 60.0  # a stalled response's connection is held at most this long


class State:
    def __init__(self, args):
        self.args = args
        self.lock = threading.Lock()
        self.payload_requests = {}
        self.faults = {}
        self.first_payload = {}
        self.log = open(args.log, "a", buffering=1) if args.log else None

    def fault_for(self, run, start, path):
        """The number of this payload request's fault in run (its URL's first
        folder), or 0 (counts it)."""
        if run.split("-", 1)[0] not in KINDS or start < HEADER_SIZE:
            return 0
        table = node_table(path)
        if table and (table[0] <= start < table[0] + table[1] or (table[2] and start >= table[2])):
            return 0
        every, most = self.args.every, self.args.max
        m = re.fullmatch(r"e(\d+)(?:m(\d+))?", run.split("-", 1)[1]) if "-" in run else None
        if m:
            every = max(1, int(m.group(1)))
            most = int(m.group(2)) if m.group(2) else most
        with self.lock:
            now = time.monotonic()
            first = self.first_payload.setdefault(run, now)
            n = self.payload_requests[run] = self.payload_requests.get(run, 0) + 1
            k = self.faults.get(run, 0)
            if k >= most or now - first > self.args.for_s or n % every:
                return 0
            self.faults[run] = k + 1
            return k + 1

    def note(self, n, run, rng):
        if self.log:
            self.log.write("fault %d %s bytes=%d-%d at %d\n" %
                           (n, run, rng[0], rng[1], int(time.time() * 1000)))


def node_table(path):
    """(offset, size) of a store's node table and the extras table's offset
    (0: none), or None."""
    try:
        with open(path, "rb") as f:
            h = f.read(HEADER_SIZE)
    except OSError:
        return None
    if len(h) < HEADER_SIZE or not h.startswith(b"HLODSTOR"):
        return None
    return struct.unpack_from("<QQ", h, 56) + struct.unpack_from("<Q", h, 240)


class Handler(http.server.BaseHTTPRequestHandler):
    protocol_version = "HTTP/1.1"
    server_version = "hlod-fault/1"

    def log_message(self, fmt, *a):
        pass

    def do_HEAD(self):
        self.serve(body=False)

    def do_GET(self):
        self.serve(body=True)

    def serve(self, body):
        st = self.server.state
        rel = self.path.split("?", 1)[0].lstrip("/")
        run = rel.split("/", 1)[0]
        kind = run.split("-", 1)[0]
        if kind in KINDS and "/" in rel:
            rel = rel[len(run) + 1:]
        else:
            run = kind = ""
        path = os.path.realpath(os.path.join(st.args.root, rel))
        if not path.startswith(os.path.realpath(st.args.root) + os.sep) or not os.path.isfile(path):
            self.send_response(404)
            self.send_header("Content-Length", "0")
            self.end_headers()
            return
        sz = os.path.getsize(path)
        mt = os.stat(path).st_mtime_ns
        etag = '"%x-%x"' % (mt, sz)
        lm = email.utils.formatdate(mt / 1e9, usegmt=True)
        rng = self.headers.get("Range")
        if_range = self.headers.get("If-Range")
        if rng and if_range and if_range not in (etag, lm):
            rng = None  # the validator changed: the whole file
        span = None
        if rng:
            try:
                unit, spec = rng.split("=", 1)
                a, b = spec.split("-", 1)
                if unit.strip() != "bytes" or "," in spec:
                    raise ValueError
                if a == "":
                    n = int(b)
                    a, b = max(sz - n, 0), sz - 1
                else:
                    a, b = int(a), (int(b) if b else sz - 1)
                span = (a, min(b, sz - 1))
            except ValueError:
                span = None
            if span and span[0] >= sz:
                self.send_response(416)
                self.send_header("Content-Range", "bytes */%d" % sz)
                self.send_header("Content-Length", "0")
                self.end_headers()
                return
        if span:
            fault = st.fault_for(run, span[0], path)
            kind = kind if fault else None
            if kind:
                st.note(fault, run, span)
            if kind == "416":
                self.send_response(416)
                self.send_header("Content-Range", "bytes */%d" % sz)
                self.send_header("Content-Length", "0")
                self.send_header("ETag", etag)
                self.end_headers()
                return
            if kind == "reset" and fault % 2 == 1:
                self.reset()
                return
            n = span[1] - span[0] + 1
            self.send_response(206)
            self.send_header("Content-Range", "bytes %d-%d/%d" % (span[0], span[1], sz))
        else:
            kind = None
            span = (0, sz - 1)
            n = sz
            self.send_response(200)
        self.send_header("Content-Length", str(n))
        self.send_header("ETag", etag)
        self.send_header("Last-Modified", lm)
        self.send_header("Accept-Ranges", "bytes")
        self.send_header("Content-Type", "application/octet-stream")
        self.end_headers()
        if not body:
            return
        send = n if not kind else max(1, n // 2)
        with open(path, "rb") as f:
            off, left = span[0], send
            while left > 0:
                chunk = os.pread(f.fileno(), min(left, 1 << 20), off)
                if not chunk:
                    break
                self.wfile.write(chunk)
                off += len(chunk)
                left -= len(chunk)
        if kind == "truncate":
            self.close_connection = True  # FIN after half the body
        elif kind == "reset":
            self.reset()
        elif kind == "stall":
            self.stall()

    def stall(self):
        """Sends nothing more until the client closes (or STALL_S)."""
        self.wfile.flush()
        self.connection.settimeout(STALL_S)
        try:
            while self.connection.recv(4096):
                pass  # a client that sends more is still waiting
        except OSError:
            pass
        self.close_connection = True

    def reset(self):
        """Closes the connection with an RST (SO_LINGER 0), no FIN first."""
        self.connection.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
        with self.server.reset_lock:
            self.server.to_reset.add(self.connection)
        self.close_connection = True


class Server(socketserver.ThreadingMixIn, http.server.HTTPServer):
    daemon_threads = True
    allow_reuse_address = True
    request_queue_size = 64

    def handle_error(self, request, client_address):
        if not isinstance(sys.exc_info()[1], (ConnectionError, TimeoutError)):
            super().handle_error(request, client_address)  # a client gone is no news

    def shutdown_request(self, request):
        with self.reset_lock:
            rst = request in self.to_reset
            self.to_reset.discard(request)
        if rst:
            request.close()  # no shutdown(SHUT_WR): that would send a FIN first
        else:
            super().shutdown_request(request)


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--root", required=True)
    p.add_argument("--port", type=int, default=0)
    p.add_argument("--port-file")
    p.add_argument("--every", type=int, default=3, help="every Nth payload request (default 3)")
    p.add_argument("--max", type=int, default=1 << 30, help="faults at most (default: no limit)")
    p.add_argument("--for", dest="for_s", type=float, default=1e9,
                   help="seconds after the first payload request (default: no limit)")
    p.add_argument("--log")
    args = p.parse_args()
    if args.every < 1:
        p.error("--every must be >= 1")
    srv = Server(("127.0.0.1", args.port), Handler)
    srv.state = State(args)
    srv.to_reset = set()
    srv.reset_lock = threading.Lock()
    if args.port_file:
        tmp = args.port_file + ".tmp"
        with open(tmp, "w") as f:
            f.write("%d\n" % srv.server_address[1])
        os.rename(tmp, args.port_file)
    try:
        srv.serve_forever()
    except KeyboardInterrupt:
        pass
    return 0


if __name__ == "__main__":
    sys.exit(main())
