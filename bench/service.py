"""Benchmark of the job service's API: latency under concurrency and memory while a big upload streams in.

Run from the repository root:

    python bench/service.py            # about 1-3 minutes on 2 cores; writes bench/results/service.md

What it does
------------
1. Starts the API alone (`python -m cloud2cnc.cli serve --no-worker`, i.e. `cloud2cnc serve --no-worker`) as a
   separate uvicorn process on 127.0.0.1 with a temporary data directory (SQLite, filesystem:// broker). No
   worker runs, so created jobs stay `queued`: the numbers are the API's own cost, not the pipeline's.
2. Drives it with N concurrent clients (threads with http.client, one keep-alive connection each):
   `GET /healthz` (the baseline: the cheapest route of the same server), `POST /v1/jobs` with a small XYZ cloud,
   `GET /v1/jobs/{id}` over the jobs just created, and `GET /healthz` again to show drift.
   Latency is measured at the client, per request, from send to full response.
3. Streams a 200 MiB binary PLY from disk (the client never holds it: a generator reads 1 MiB at a time) and
   samples the server's resident memory (process and children, psutil, every 20 ms) from idle to response.
4. Starts a second server with CLOUD2CNC_MAX_UPLOAD_MB=50 and sends the same file, which must get 413 with
   memory flat, once with a Content-Length header and once chunked (no length: refused on the running count).
5. API latency while a stage computes: `cloud2cnc serve` with its embedded worker, `GET /v1/jobs/{id}` paced
   (a dashboard's polling) while the worker is idle and while it runs the README example's `fit` on the same
   CPUs, once with the worker niced (CLOUD2CNC_WORKER_NICE=10, the default) and once not (0).
   `python bench/service.py --only busy` (3-6 minutes, most of it waiting for the job to reach fit) runs this
   part alone and replaces its section of bench/results/service.md, leaving the rest as it was.

The module is named service.py: it must not `import service` (that would find itself); it talks to the
service over HTTP only.
"""

from __future__ import annotations

import argparse
import datetime as dt
import http.client
import itertools
import json
import os
import platform
import random
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from collections import Counter
from pathlib import Path

import httpx
import numpy as np
import psutil
from machine_info import cpu_model  # bench/ is on the path when a script runs

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "bench" / "results" / "service.md"
MiB = 1024 * 1024
LIMIT_DELTA_MB = 100.0


# --------------------------------------------------------------------------- server process

class Server:
    """`cloud2cnc serve --no-worker` (or, with `worker`, with its embedded worker) on a free loopback port, in
    its own process group."""

    def __init__(self, root: Path, name: str, env_extra: dict[str, str] | None = None, *,
                 worker: bool = False) -> None:
        self.data_dir = root / f"data-{name}"
        self.log_path = root / f"server-{name}.log"
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            self.port = s.getsockname()[1]
        self.base = f"http://127.0.0.1:{self.port}"
        env = {k: v for k, v in os.environ.items()
               if k not in ("DATABASE_URL", "CELERY_BROKER_URL", "CLOUD2CNC_API_KEY", "CLOUD2CNC_MAX_UPLOAD_MB",
                            "CLOUD2CNC_WORKER_NICE", "CLOUD2CNC_STAGE_PLUGINS", "CLOUD2CNC_PIPELINE")}
        env.update(env_extra or {})
        self._log = open(self.log_path, "wb")  # noqa: SIM115 — closed in stop()
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "cloud2cnc.cli", "serve", *([] if worker else ["--no-worker"]),
             "--host", "127.0.0.1", "--port", str(self.port), "--data-dir", str(self.data_dir),
             "--log-level", "warning"],
            cwd=REPO, env=env, stdout=self._log, stderr=subprocess.STDOUT, start_new_session=True)
        self.ps = psutil.Process(self.proc.pid)

    def wait_ready(self, timeout_s: float = 60.0) -> None:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"server exited with {self.proc.returncode}:\n{self.log_tail()}")
            try:
                if httpx.get(self.base + "/healthz", timeout=1.0).status_code == 200:
                    return
            except httpx.HTTPError:
                pass
            time.sleep(0.1)
        raise RuntimeError(f"server not ready after {timeout_s:.0f} s:\n{self.log_tail()}")

    def rss(self) -> int:
        """Resident bytes of the server process and all its children."""
        total = 0
        try:
            procs = [self.ps] + self.ps.children(recursive=True)
        except psutil.NoSuchProcess:
            return 0
        for p in procs:
            try:
                total += p.memory_info().rss
            except psutil.NoSuchProcess:
                pass
        return total

    def log_tail(self, n: int = 4000) -> str:
        if not self._log.closed:
            self._log.flush()
        return self.log_path.read_bytes()[-n:].decode("utf-8", "replace")

    def exceptions(self) -> Counter:
        """Exception lines (`pkg.Error: message`) in the server's log, counted."""
        found: Counter = Counter()
        if self.log_path.exists():
            for line in self.log_path.read_text("utf-8", "replace").splitlines():
                if re.match(r"^[A-Za-z_][\w.]*(Error|Exception|Timeout)\b.*?: ", line):
                    found[line[:300]] += 1
        return found

    def stop(self) -> None:
        if self.proc.poll() is None:
            for sig, wait in ((signal.SIGTERM, 10.0), (signal.SIGKILL, 5.0)):
                try:
                    os.killpg(self.proc.pid, sig)
                except ProcessLookupError:
                    break
                try:
                    self.proc.wait(timeout=wait)
                    break
                except subprocess.TimeoutExpired:
                    continue
        self._log.close()


# --------------------------------------------------------------------------- latency under load

def small_clouds(n: int, points: int, seed: int = 0) -> list[bytes]:
    """n distinct ~200-point XYZ clouds (`x y z` lines), so each POST stores a new input."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        pts = rng.uniform(-50.0, 50.0, size=(points, 3))
        out.append("".join(f"{x:.4f} {y:.4f} {z:.4f}\n" for x, y, z in pts).encode())
    return out


def multipart(fields: list[tuple[str, str | None, bytes]], boundary: str | None = None) -> tuple[bytes, str]:
    """(body, content type) of a multipart/form-data body; each field is (name, filename or None, bytes)."""
    boundary = boundary or uuid.uuid4().hex
    parts = []
    for name, filename, data in fields:
        disp = f'form-data; name="{name}"' + (f'; filename="{filename}"' if filename else "")
        parts.append(f"--{boundary}\r\nContent-Disposition: {disp}\r\n\r\n".encode() + data + b"\r\n")
    return b"".join(parts) + f"--{boundary}--\r\n".encode(), f"multipart/form-data; boundary={boundary}"


def _cpu_s(server: Server) -> float:
    try:
        t = server.ps.cpu_times()
        return t.user + t.system
    except psutil.NoSuchProcess:
        return float("nan")


def _load(server: Server, request, n: int, clients: int, expected: int, timeout_s: float,
          request_timeout_s: float) -> dict:
    """n requests from `clients` threads, one keep-alive connection each; no new request after `timeout_s`.

    `request(i)` returns (method, path, body, headers). http.client in threads is the load generator: it
    costs the shared CPUs about a tenth of what httpx's async client does per request.
    """
    lock = threading.Lock()
    latencies: list[float] = []  # of the responses with the expected status only
    statuses: Counter = Counter()
    errors: Counter = Counter()
    samples: dict = {}  # first body of each unexpected status
    bodies: list[bytes] = []
    numbers = itertools.count()
    deadline = time.perf_counter() + timeout_s
    host, port = "127.0.0.1", server.port

    def one_client() -> None:
        conn = None
        while True:
            i = next(numbers)
            if i >= n or time.perf_counter() > deadline:
                break
            method, path, body, headers = request(i)
            if conn is None:
                conn = http.client.HTTPConnection(host, port, timeout=request_timeout_s)
            t0 = time.perf_counter()
            try:
                conn.request(method, path, body=body, headers=headers)
                resp = conn.getresponse()
                data = resp.read()
            except (OSError, http.client.HTTPException) as exc:
                conn.close()
                conn = None
                with lock:
                    errors[type(exc).__name__] += 1
                continue
            dt_s = time.perf_counter() - t0
            with lock:
                statuses[resp.status] += 1
                if resp.status == expected:
                    latencies.append(dt_s)
                    bodies.append(data)
                else:
                    samples.setdefault(resp.status, data[:200].decode("utf-8", "replace"))
            if resp.will_close:
                conn.close()
                conn = None
        if conn is not None:
            conn.close()

    cpu0 = _cpu_s(server)
    t0 = time.perf_counter()
    threads = [threading.Thread(target=one_client, daemon=True) for _ in range(clients)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    wall = time.perf_counter() - t0
    cpu = _cpu_s(server) - cpu0
    lat_ms = np.array(latencies) * 1000.0
    sent = sum(statuses.values()) + sum(errors.values())

    def stat(fn):
        return float(fn(lat_ms)) if len(lat_ms) else float("nan")

    return {
        "requested": n, "sent": sent, "ok": len(latencies), "clients": clients, "wall_s": wall,
        "rps": len(latencies) / wall if wall else 0.0,
        "p50": stat(lambda a: np.percentile(a, 50)), "p99": stat(lambda a: np.percentile(a, 99)),
        "mean": stat(np.mean), "max": stat(np.max),
        "cpu_ms": 1000.0 * cpu / sent if sent else float("nan"),
        "statuses": dict(statuses), "errors": dict(errors), "samples": samples, "responses": bodies,
        "cut_short": sent < n,
    }


def latency_phases(server: Server, n: int, clients: int, safe_clients: int, timeout_s: float,
                   request_timeout_s: float) -> dict[str, dict]:
    clouds = small_clouds(2 * n + 2 * clients, 200)
    next_cloud = itertools.count()
    rt = request_timeout_s

    def healthz(i):
        return "GET", "/healthz", None, {}

    def post_job(i):
        k = next(next_cloud)
        body, ctype = multipart([("file", f"cloud{k}.xyz", clouds[k]), ("params", None, b"{}")])
        return "POST", "/v1/jobs", body, {"Content-Type": ctype}

    out: dict[str, dict] = {}
    # Warm-up (not counted): opens connections, fills caches and the database's first pages.
    _load(server, healthz, 4 * clients, clients, 200, timeout_s, rt)
    _load(server, post_job, 2 * safe_clients, safe_clients, 202, timeout_s, rt)
    out["healthz_safe"] = _load(server, healthz, n, safe_clients, 200, timeout_s, rt)
    out["post_safe"] = _load(server, post_job, n, safe_clients, 202, timeout_s, rt)
    ids = [json.loads(b)["id"] for b in out["post_safe"]["responses"]]
    if not ids:
        raise RuntimeError(f"no job was created: {out['post_safe']}")
    rng = random.Random(1)
    order = [rng.choice(ids) for _ in range(n)]

    def get_job(i):
        return "GET", f"/v1/jobs/{order[i]}", None, {}

    out["healthz"] = _load(server, healthz, n, clients, 200, timeout_s, rt)
    out["get"] = _load(server, get_job, n, clients, 200, timeout_s, rt)
    # Last, with a healthz check after it: this phase once hung the API (a pinned pool connection).
    out["post"] = _load(server, post_job, n, clients, 202, min(timeout_s, 45.0), rt)
    out["healthz_after"] = _load(server, healthz, n, clients, 200, 15.0, rt)
    for v in out.values():
        v.pop("responses", None)
    out["jobs_created"] = {"count": len(ids) + out["post"]["ok"]}
    return out


# --------------------------------------------------------------------------- big upload

def write_big_ply(path: Path, size_bytes: int, seed: int = 0) -> int:
    """A valid binary little-endian PLY of float32 x y z points, `size_bytes` long; returns the point count."""
    header_tmpl = "ply\nformat binary_little_endian 1.0\ncomment cloud2cnc bench\nelement vertex {:>10d}\n" \
                  "property float x\nproperty float y\nproperty float z\nend_header\n"
    header_len = len(header_tmpl.format(0).encode())
    n = (size_bytes - header_len) // 12
    rng = np.random.default_rng(seed)
    with open(path, "wb") as fh:
        fh.write(header_tmpl.format(n).encode())
        left = n
        while left:
            k = min(left, 1 << 20)
            fh.write(rng.uniform(-100.0, 100.0, size=(k, 3)).astype("<f4").tobytes())
            left -= k
    return n


class Sampler(threading.Thread):
    """Samples the server's RSS every `interval_s` until stopped."""

    def __init__(self, server: Server, interval_s: float = 0.02) -> None:
        super().__init__(daemon=True)
        self.server, self.interval_s = server, interval_s
        self.samples: list[int] = []
        self._stop_event = threading.Event()

    def run(self) -> None:
        while not self._stop_event.is_set():
            self.samples.append(self.server.rss())
            self._stop_event.wait(self.interval_s)

    def stop(self) -> list[int]:
        self._stop_event.set()
        self.join()
        return self.samples


class Prober(threading.Thread):
    """GET /healthz every 50 ms while the upload runs: shows whether the upload blocks the server."""

    def __init__(self, base: str) -> None:
        super().__init__(daemon=True)
        self.base = base
        self.latencies: list[float] = []
        self.failures = 0
        self._stop_event = threading.Event()

    def run(self) -> None:
        with httpx.Client(base_url=self.base, timeout=30.0) as c:
            while not self._stop_event.is_set():
                t0 = time.perf_counter()
                try:
                    c.get("/healthz").raise_for_status()
                    self.latencies.append(time.perf_counter() - t0)
                except httpx.HTTPError:
                    self.failures += 1
                self._stop_event.wait(0.05)

    def exceptions(self) -> Counter:
        """Exception lines (`pkg.Error: message`) in the server's log, counted."""
        found: Counter = Counter()
        if self.log_path.exists():
            for line in self.log_path.read_text("utf-8", "replace").splitlines():
                if re.match(r"^[A-Za-z_][\w.]*(Error|Exception|Timeout)\b.*?: ", line):
                    found[line[:300]] += 1
        return found

    def stop(self) -> None:
        self._stop_event.set()
        self.join()


def upload(server: Server, path: Path, *, chunked: bool, label: str) -> dict:
    """Stream `path` as the `file` part of POST /v1/jobs and watch the server's memory meanwhile."""
    boundary = uuid.uuid4().hex
    head = (f'--{boundary}\r\nContent-Disposition: form-data; name="params"\r\n\r\n{{}}\r\n'
            f'--{boundary}\r\nContent-Disposition: form-data; name="file"; filename="{path.name}"\r\n'
            f'Content-Type: application/octet-stream\r\n\r\n').encode()
    tail = f"\r\n--{boundary}--\r\n".encode()
    size = path.stat().st_size
    sent = [0]

    def body():
        yield head
        sent[0] += len(head)
        with open(path, "rb") as fh:
            while chunk := fh.read(MiB):
                yield chunk
                sent[0] += len(chunk)
        yield tail
        sent[0] += len(tail)

    headers = {"Content-Type": f"multipart/form-data; boundary={boundary}"}
    if not chunked:
        headers["Content-Length"] = str(len(head) + size + len(tail))

    time.sleep(1.0)  # let the server settle, then take idle as the median of 1 s of samples
    idle_samples = []
    for _ in range(50):
        idle_samples.append(server.rss())
        time.sleep(0.02)
    idle = float(np.median(idle_samples))
    me = psutil.Process()
    client_before = me.memory_info().rss
    sampler, prober = Sampler(server), Prober(server.base)
    sampler.start()
    prober.start()
    status, detail, error = None, "", ""
    t0 = time.perf_counter()
    try:
        with httpx.Client(base_url=server.base, timeout=httpx.Timeout(120.0)) as c:
            r = c.post("/v1/jobs", content=body(), headers=headers)
            status = r.status_code
            try:
                js = r.json()
                detail = js.get("type") or js.get("status") or ""
            except ValueError:
                detail = r.text[:120]
    except httpx.HTTPError as exc:
        error = f"{type(exc).__name__}: {exc}"
    elapsed = time.perf_counter() - t0
    prober.stop()
    time.sleep(1.0)
    samples = sampler.stop()
    after = server.rss()
    client_peak_delta = me.memory_info().rss - client_before
    peak = max(samples) if samples else float("nan")
    lat = np.array(prober.latencies) * 1000.0
    left = sorted(p.name for p in (server.data_dir / "uploads").glob("upload-*")) \
        if (server.data_dir / "uploads").is_dir() else []
    return {
        "label": label, "status": status, "type": detail, "error": error, "chunked": chunked,
        "sent_mb": sent[0] / MiB, "file_mb": size / MiB, "time_s": elapsed, "mb_s": sent[0] / MiB / elapsed,
        "idle_mb": idle / MiB, "peak_mb": peak / MiB, "delta_mb": (peak - idle) / MiB, "after_mb": after / MiB,
        "samples": len(samples),
        "probe_p50": float(np.percentile(lat, 50)) if len(lat) else float("nan"),
        "probe_max": float(lat.max()) if len(lat) else float("nan"),
        "probe_n": len(lat), "probe_fail": prober.failures,
        "client_delta_mb": client_peak_delta / MiB, "leftover_uploads": left,
    }


# --------------------------------------------------------------------------- latency while a stage computes

EXAMPLE = REPO / "examples" / "dome_block.xyz"
#: The README's example job: a real pipeline whose `fit` keeps both CPUs busy for tens of seconds.
EXAMPLE_PARAMS = {"tool": {"radius_mm": 2}, "reconstruct": {"max_faces": 20000}, "fit": {"max_refinements": 0}}
BUSY_STAGE = "fit"
BUSY_TARGET = 3.0  # p99 while a stage computes ≤ 3 × idle p99 (issue 38)
BUSY_SECTION = "## API latency while a stage computes"
FINAL = ("succeeded", "failed", "canceled")


def _tree(server: Server) -> list[psutil.Process]:
    """serve's descendants: the embedded worker, its pool and the processes its stage forked."""
    try:
        return server.ps.children(recursive=True)
    except psutil.NoSuchProcess:
        return []


def _tree_cpu_s(server: Server) -> float:
    """CPU seconds of serve's descendants, including those of their children already reaped."""
    total = 0.0
    for p in _tree(server):
        try:
            t = p.cpu_times()
            total += t.user + t.system + t.children_user + t.children_system
        except psutil.NoSuchProcess:
            pass
    return total


def _job(server: Server, job_id: str) -> dict:
    return httpx.get(f"{server.base}/v1/jobs/{job_id}", timeout=30.0).json()


def _running(job: dict) -> list[str]:
    return [st["name"] for st in job.get("stages", []) if st["status"] == "running"]


def _submit(server: Server, name: str, data: bytes, params: dict) -> str:
    r = httpx.post(f"{server.base}/v1/jobs", files={"file": (name, data)}, data={"params": json.dumps(params)},
                   timeout=60.0)
    if r.status_code != 202:
        raise RuntimeError(f"POST /v1/jobs answered {r.status_code}: {r.text[:300]}")
    return r.json()["id"]


def _wait_job(server: Server, job_id: str, done, timeout_s: float) -> dict:
    deadline = time.monotonic() + timeout_s
    while True:
        job = _job(server, job_id)
        if done(job) or job["status"] in FINAL or time.monotonic() > deadline:
            return job
        time.sleep(0.5)


def _paced_gets(server: Server, job_id: str, heavy_id: str | None, n: int, clients: int,
                interval_s: float) -> dict:
    """`GET /v1/jobs/{job_id}` n times from `clients` threads, each waiting `interval_s` before each request
    (a dashboard polling, not a flood); with the worker's CPU use and the heavy job's stages meanwhile."""
    path = f"/v1/jobs/{job_id}"

    def get(i):
        time.sleep(interval_s)  # before t0 in _load: pacing, not latency
        return "GET", path, None, {}

    before = _running(_job(server, heavy_id)) if heavy_id else []
    psutil.cpu_percent(None)
    cpu0, t0 = _tree_cpu_s(server), time.perf_counter()
    r = _load(server, get, n, clients, 200, 120.0, 30.0)
    wall = time.perf_counter() - t0
    r["worker_cores"] = (_tree_cpu_s(server) - cpu0) / wall
    r["machine_cpu_pct"] = psutil.cpu_percent(None)
    after = _running(_job(server, heavy_id)) if heavy_id else []
    r["stages"] = list(dict.fromkeys(before + after))
    r["stage_through"] = bool(heavy_id) and BUSY_STAGE in before and BUSY_STAGE in after
    r.pop("responses", None)
    return r


def busy_run(root: Path, nice: int, n: int, clients: int, interval_s: float, wait_s: float) -> dict:
    """One `serve` with its worker at `nice`: GET latency idle, then while the example job's `fit` runs."""
    server = Server(root, f"busy-nice{nice}", {"CLOUD2CNC_WORKER_NICE": str(nice)}, worker=True)
    tree: list[psutil.Process] = []
    try:
        server.wait_ready()
        # The job every GET reads, idle and busy alike: 20 points, which ingest refuses at once.
        probe = _submit(server, "probe.xyz", small_clouds(1, 20, seed=7)[0], {})
        if _wait_job(server, probe, lambda j: False, 60.0)["status"] not in FINAL:
            raise RuntimeError(f"the probe job did not finish:\n{server.log_tail()}")
        time.sleep(1.0)
        tree = _tree(server)
        nices = sorted({p.nice() for p in tree})
        idle = _paced_gets(server, probe, None, n, clients, interval_s)
        heavy = _submit(server, EXAMPLE.name, EXAMPLE.read_bytes(), EXAMPLE_PARAMS)
        t_submit = time.perf_counter()
        job = _wait_job(server, heavy, lambda j: BUSY_STAGE in _running(j), wait_s)
        if BUSY_STAGE not in _running(job):
            raise RuntimeError(f"stage {BUSY_STAGE} not running after {wait_s:.0f} s: {_running(job)} "
                               f"{job['status']}\n{server.log_tail()}")
        reached = time.perf_counter() - t_submit
        busy = _paced_gets(server, probe, heavy, n, clients, interval_s)
        tree = _tree(server)
        return {"nice": nice, "process_nices": nices, "idle": idle, "busy": busy, "fit_after_s": reached}
    finally:
        tree = tree + _tree(server)
        server.stop()
        _, alive = psutil.wait_procs(tree, timeout=20)
        for proc in alive:
            proc.kill()


def render_busy(runs: list[dict], args, m: dict, machine_line: str, load_before: tuple, load_after: tuple,
                total_s: float) -> str:
    out = [
        BUSY_SECTION + " (`GET /v1/jobs/{id}`)",
        "",
        (f"Machine: {machine_line}. Load average (1 / 5 / 15 min) {load_before[0]:.1f} / {load_before[1]:.1f} / "
         f"{load_before[2]:.1f} before this part, {load_after[0]:.1f} / {load_after[1]:.1f} / {load_after[2]:.1f} "
         f"after it (anything over 0 is other work sharing the CPUs, another engineer's included); commit "
         f"{m['commit']}; {m['date']}; {total_s:.0f} s. Reproduce: `python bench/service.py --only busy`."),
        "",
        (f"Target (issue 38): with the embedded worker niced (`CLOUD2CNC_WORKER_NICE`, default 10), p99 while a "
         f"stage computes ≤ {BUSY_TARGET:.0f} × p99 idle. The not-niced rows (0) are the same measurement with the "
         f"priority of the code before it, in the same run."),
        "",
        ("| worker niceness | phase | stages running | ok / sent | p50 ms | p99 ms | max ms | worker CPU, cores | "
         "machine CPU % | API CPU ms/req | p99 × idle p99 | target |"),
        "|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---|",
    ]
    for run in runs:
        label = f"{run['nice']}" + (" (default)" if run["nice"] == 10 else " (not niced)" if run["nice"] == 0 else "")
        label += f"; processes at {', '.join(str(v) for v in run['process_nices'])}"
        for phase in ("idle", "busy"):
            r, idle = run[phase], run["idle"]
            stages = ", ".join(r["stages"]) or "–"
            if phase == "busy" and not r["stage_through"]:
                stages += f" ({BUSY_STAGE} not running the whole phase)"
            ratio = "–" if phase == "idle" else _ratio(r["p99"], idle["p99"])
            verdict = "" if phase == "idle" or run["nice"] == 0 else (
                "met" if r["p99"] <= BUSY_TARGET * idle["p99"] else "**missed**")
            out.append(f"| {label} | {phase} | {stages} | {r['ok']} / {r['sent']} | {_ms(r['p50'])} | "
                       f"{_ms(r['p99'])} | {_ms(r['max'])} | {r['worker_cores']:.2f} | {r['machine_cpu_pct']:.0f} | "
                       f"{_ms(r['cpu_ms'], 2)} | {ratio} | {verdict} |")
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    if max(load_before[0], load_after[0]) > cpus:
        out += ["", (f"**Other work saturated the machine during this run** (load average up to "
                     f"{max(load_before[0], load_after[0]):.1f} on {cpus} CPUs): the idle rows are not idle, the "
                     f"stage got only the worker CPU shown, and the ratios measure that other work more than the "
                     f"worker; what niceness changes shows only on a machine that is otherwise quiet.")]
    notes = [f"niceness {run['nice']} {ph}: {_notes(run[ph], 200)}" for run in runs for ph in ("idle", "busy")
             if _notes(run[ph], 200)]
    if notes:
        out += ["", "Unexpected answers: " + "; ".join(notes) + "."]
    out += [
        "",
        (f"How measured: for each niceness, `bench/service.py` starts `cloud2cnc serve` with its embedded worker "
         f"(SQLite, `filesystem://` broker, a fresh temporary data directory; `CLOUD2CNC_WORKER_NICE` set to it) "
         f"and submits a 20-point cloud, which ingest refuses at once: that job is the one every GET reads, so "
         f"idle and busy requests ask for exactly the same thing. {args.busy_clients} client threads (http.client, "
         f"keep-alive) each wait {args.busy_interval_ms:.0f} ms and then send `GET /v1/jobs/{{id}}`, "
         f"{args.busy_requests} requests per phase, latency from send to full response, as a dashboard polls. "
         f"Idle: with the worker waiting for work. Busy: after the README example job (`examples/dome_block.xyz`, "
         f"`{json.dumps(EXAMPLE_PARAMS)}`) has reached `{BUSY_STAGE}`, which forks one process per CPU for its "
         f"patches; the stages column lists what ran during the phase. Worker CPU is the CPU time of everything "
         f"under `serve` (worker, pool, forked children) over the phase's wall time; machine CPU % is psutil's "
         f"over the same window (all CPUs, 100 % = all busy, other work included); API CPU is the `serve` "
         f"process's per request. Niceness only changes who runs first when the API and the stage both want a "
         f"CPU: the worker CPU of the two busy rows shows how much the stage computed meanwhile."),
        "",
    ]
    return "\n".join(out)


def splice_section(text: str, section: str) -> str:
    """`text` with its `BUSY_SECTION` (up to the next `## ` heading) replaced by `section`, or `section` appended."""
    lines = text.rstrip("\n").split("\n")
    start = next((i for i, line in enumerate(lines) if line.startswith(BUSY_SECTION)), None)
    if start is None:
        return "\n".join(lines) + "\n\n" + section.rstrip("\n") + "\n"
    end = next((i for i in range(start + 1, len(lines)) if lines[i].startswith("## ")), len(lines))
    kept_after = lines[end:]
    return "\n".join(lines[:start] + section.rstrip("\n").split("\n") + ([""] + kept_after if kept_after else [])) \
        + "\n"


def run_busy(root: Path, args) -> tuple[list[dict], str, tuple, tuple, float]:
    from machine_info import describe_machine

    t0, load_before, line = time.perf_counter(), os.getloadavg(), describe_machine()
    runs = []
    for nice in (10, 0):
        print(f"busy: serve with its worker at niceness {nice} ...", flush=True)
        runs.append(busy_run(root, nice, args.busy_requests, args.busy_clients, args.busy_interval_ms / 1000.0,
                             args.busy_wait))
        for phase in ("idle", "busy"):
            r = runs[-1][phase]
            print(f"  {phase}: p50={r['p50']:.1f} ms p99={r['p99']:.1f} ms ok={r['ok']}/{r['sent']} "
                  f"worker={r['worker_cores']:.2f} cores stages={r['stages']}", flush=True)
    return runs, line, load_before, os.getloadavg(), time.perf_counter() - t0


# --------------------------------------------------------------------------- report

def machine() -> dict:
    model = cpu_model()
    try:
        nproc = subprocess.run(["nproc"], capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        nproc = str(len(os.sched_getaffinity(0)))
    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO, capture_output=True,
                                text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain"], cwd=REPO, capture_output=True,
                               text=True, check=False).stdout.strip()
        commit += " (working tree modified)" if dirty else ""
    except (OSError, subprocess.CalledProcessError):
        commit = "unknown"
    import uvicorn  # only for its version

    return {"nproc": nproc, "cpu": model, "date": dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC"),
            "python": platform.python_version(), "uvicorn": uvicorn.__version__, "httpx": httpx.__version__,
            "commit": commit, "mem_gb": psutil.virtual_memory().total / 2**30}


def _notes(r: dict, expected: int) -> str:
    bad = {s: c for s, c in r["statuses"].items() if s != expected}
    parts = [f"{c}× HTTP {s}" for s, c in sorted(bad.items())]
    parts += [f"{c}× {e} (client timeout)" if "Timeout" in e else f"{c}× {e}" for e, c in r["errors"].items()]
    if r["cut_short"]:
        parts.append(f"phase stopped at its time limit after {r['sent']} of {r['requested']}")
    return "**" + "; ".join(parts) + "**" if parts else ""


def _ms(v: float, digits: int = 1) -> str:
    return "–" if np.isnan(v) else f"{v:.{digits}f}"


def _ratio(v: float, base: float) -> str:
    return "n/a" if np.isnan(v) or np.isnan(base) or not base else f"{v / base:.2f}"


def render(lat: dict, ups: list[dict], args, m: dict, total_s: float, server_errors: Counter,
           load_before: tuple[float, float, float]) -> str:
    rows = [  # label, key, expected status, baseline key
        ("`GET /healthz` (baseline)", "healthz_safe", 200, "healthz_safe"),
        ("`POST /v1/jobs` (200-point XYZ)", "post_safe", 202, "healthz_safe"),
        ("`GET /healthz` (baseline)", "healthz", 200, "healthz"),
        ("`GET /v1/jobs/{id}`", "get", 200, "healthz"),
        ("`POST /v1/jobs` (200-point XYZ)", "post", 202, "healthz"),
        ("`GET /healthz` (right after the POST phase)", "healthz_after", 200, "healthz"),
    ]
    out = [
        "# Service benchmark: API latency and upload memory",
        "",
        (f"Machine: {m['nproc']} CPUs (`nproc`), {m['cpu']}, {m['mem_gb']:.0f} GiB RAM; Python {m['python']}, "
         f"uvicorn {m['uvicorn']}, httpx {m['httpx']}; commit {m['commit']}; {m['date']}. "
         f"Whole run: {total_s:.0f} s; load average before it {load_before[0]:.1f} / {load_before[1]:.1f} / "
         f"{load_before[2]:.1f} (1 / 5 / 15 min; anything over 0 is other work sharing the CPUs). "
         f"Reproduce: `python bench/service.py`."),
        "",
        f"## Latency ({args.requests} requests per row)",
        "",
        ("Each route's ratio is against `GET /healthz` of the same server, same run, same number of concurrent "
         "clients (the baseline row above it). Latency figures are over the requests that got the expected "
         "status (200, or 202 for POST); anything else is in the notes."),
        "",
        ("| route | clients | ok / sent | p50 ms | p99 ms | mean ms | max ms | req/s | server CPU ms/req | "
         "p50 × baseline | p99 × baseline | notes |"),
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|",
    ]
    for label, key, expected, base_key in rows:
        r, b = lat[key], lat[base_key]
        ratios = ["–" if key == base_key else _ratio(r[q], b[q]) for q in ("p50", "p99")]
        out.append(f"| {label} | {r['clients']} | {r['ok']} / {r['sent']} | {_ms(r['p50'])} | {_ms(r['p99'])} | "
                   f"{_ms(r['mean'])} | {_ms(r['max'])} | {r['rps']:.0f} | {_ms(r['cpu_ms'], 2)} | "
                   f"{ratios[0]} | {ratios[1]} | {_notes(r, expected)} |")
    samples = [f"`{key}` HTTP {st}: `{txt}`" for _, key, _, _ in rows for st, txt in lat[key]["samples"].items()]
    if samples:
        out += ["", "First body of each unexpected status: " + "; ".join(samples)]
    if server_errors:
        out += ["", "Exceptions in the latency server's log: "
                + "; ".join(f"{c}× `{line}`" for line, c in server_errors.most_common(5))]
    out += [
        "",
        f"## Memory while a {args.upload_mb} MiB upload streams in",
        "",
        (f"Requirement: peak − idle < {LIMIT_DELTA_MB:.0f} MB. Memory is the API process's resident set (RSS, with "
         "any children), MiB."),
        "",
        ("| case | status | sent MiB | time s | MiB/s | idle MiB | peak MiB | Δ peak − idle | after MiB | "
         "`/healthz` during: p50 / max ms | Δ < 100 |"),
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---|",
    ]
    for u in ups:
        st = f"{u['status']} {u['type']}".strip() if u["status"] else f"no response ({u['error']})"
        ok = "yes" if u["delta_mb"] < LIMIT_DELTA_MB else "**NO**"
        probe = (f"{u['probe_p50']:.1f} / {u['probe_max']:.0f}" if u["probe_n"] else "–") + \
            (f" ({u['probe_fail']} failed)" if u["probe_fail"] else "")
        out.append(f"| {u['label']} | {st} | {u['sent_mb']:.0f} | {u['time_s']:.2f} | {u['mb_s']:.0f} | "
                   f"{u['idle_mb']:.1f} | {u['peak_mb']:.1f} | {u['delta_mb']:+.1f} | {u['after_mb']:.1f} | "
                   f"{probe} | {ok} |")
    leftovers = [f"{u['label']}: {u['leftover_uploads']}" for u in ups if u["leftover_uploads"]]
    if leftovers:
        out += ["", "Temporary upload files left behind: " + "; ".join(leftovers) + "."]
    client = max(u["client_delta_mb"] for u in ups)
    out += [
        "",
        "## How measured",
        "",
        (f"`bench/service.py` starts the API alone (`cloud2cnc serve --no-worker`: uvicorn, one process) on "
         f"127.0.0.1 with a fresh temporary data directory: SQLite job database and the `filesystem://` broker. "
         f"No worker runs, so every job created here stays `queued`; the figures are the API's own cost "
         f"(parse the multipart body, store the input, insert the job and its stages, send the first Celery "
         f"message), not the pipeline's. The load generator runs in the benchmark process: N threads with "
         f"`http.client`, one keep-alive connection each (a tenth of httpx's CPU cost per request, which "
         f"matters when client and server share {m['nproc']} CPUs), each taking the next request number until "
         f"{args.requests} are done or the phase's time limit passes ({args.phase_timeout:.0f} s; 45 s for POST at "
         f"{args.clients}, 15 s for the check after it; {args.request_timeout:.0f} s per request). Latency is "
         f"taken at the client from send to full response, so it includes the client's own overhead — which is "
         f"why every route is also given as a ratio to `GET /healthz` measured the same way, on the same server, "
         f"in the same run, at the same concurrency; server CPU ms/req is the API process's user+system CPU time "
         f"over the phase divided by the requests sent, which the client does not inflate. After a "
         f"warm-up ({4 * args.clients} healthz and {2 * args.safe_clients} POSTs, not counted) the phases run in "
         f"the table's order. POST sends a distinct 200-point `x y z` cloud each time with `params` = `{{}}`; GET "
         f"reads a random one of the jobs created by the POST phase before it. POST is measured at "
         f"{args.safe_clients} clients as well as at {args.clients}, and the {args.clients}-client POST phase runs "
         f"last, with a `/healthz` check after it: this phase once hung the API (a pooled connection pinned by a "
         f"session torn down on the blocked event loop, fixed in the commit 'create_job: database, store and "
         f"broker work off the event loop'), and the check shows it does not any more. "
         f"For memory, a fresh server (same settings) gets a {args.upload_mb} MiB binary little-endian PLY "
         f"(float32 x y z), written to the temporary directory first and streamed as the `file` part of a "
         f"hand-built multipart body from a generator reading 1 MiB at a time (the benchmark's own RSS grew by at "
         f"most {client:.0f} MiB). Idle is the median of 1 s of samples just before the upload; peak is the "
         f"largest psutil RSS sample, taken every 20 ms from the start of the upload until 1 s after the "
         f"response; after is 1 s after the response. A thread probes `GET /healthz` every 50 ms meanwhile, to "
         f"show whether the upload stalls other requests. \"Content-Length\" rows send the body's length, "
         f"\"chunked\" rows send none (Transfer-Encoding: chunked), so a size cap can act only on the running "
         f"byte count. The 413 rows run on a third server started with `CLOUD2CNC_MAX_UPLOAD_MB=50`. All servers "
         f"and the temporary directory are removed at the end."),
        "",
    ]
    return "\n".join(out)


def _busy_met(runs: list[dict]) -> bool:
    """The target holds for the niced runs (and every request of the part got its 200)."""
    return all(r[ph]["ok"] == r[ph]["requested"] for r in runs for ph in ("idle", "busy")) and all(
        r["busy"]["p99"] <= BUSY_TARGET * r["idle"]["p99"] for r in runs if r["nice"] > 0)


# --------------------------------------------------------------------------- main

def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--requests", type=int, default=2000, help="requests per latency row")
    ap.add_argument("--clients", type=int, default=50, help="concurrent clients")
    ap.add_argument("--safe-clients", type=int, default=10,
                    help="the lower concurrency at which POST is measured as well")
    ap.add_argument("--upload-mb", type=int, default=200, help="size of the big upload, MiB")
    ap.add_argument("--phase-timeout", type=float, default=120.0, help="time limit of one latency phase, s")
    ap.add_argument("--request-timeout", type=float, default=40.0,
                    help="client timeout of one request, s (over SQLAlchemy's 30 s pool timeout)")
    ap.add_argument("--only", choices=("all", "busy"), default="all",
                    help="busy: only the latency while a stage computes, spliced into --out")
    ap.add_argument("--busy-requests", type=int, default=600, help="GETs per phase of the busy part")
    ap.add_argument("--busy-clients", type=int, default=4, help="polling clients of the busy part")
    ap.add_argument("--busy-interval-ms", type=float, default=50.0, help="each client's wait before a GET, ms")
    ap.add_argument("--busy-wait", type=float, default=300.0,
                    help=f"longest wait, s, for the example job to reach {BUSY_STAGE}")
    ap.add_argument("--out", type=Path, default=RESULTS)
    ap.add_argument("--keep", action="store_true", help="keep the temporary directory (server logs)")
    args = ap.parse_args(argv)

    # SIGTERM ends the run through the finally below, like Ctrl-C.
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    t_start = time.perf_counter()
    load_before = os.getloadavg()
    root = Path(tempfile.mkdtemp(prefix="cloud2cnc-bench-"))
    servers: list[Server] = []
    try:
        if args.only == "busy":
            busy = run_busy(root, args)
            section = render_busy(busy[0], args, machine(), *busy[1:])
            previous = args.out.read_text() if args.out.exists() else "# Service benchmark\n"
            args.out.parent.mkdir(parents=True, exist_ok=True)
            args.out.write_text(splice_section(previous, section))
            print(f"wrote {args.out}")
            return 0 if _busy_met(busy[0]) else 1
        big = root / "big.ply"
        print(f"writing a {args.upload_mb} MiB binary PLY ...", flush=True)
        write_big_ply(big, args.upload_mb * MiB)

        a = Server(root, "latency")
        servers.append(a)
        a.wait_ready()
        print(f"API on {a.base}; latency phases ({args.requests} requests each) ...", flush=True)
        lat = latency_phases(a, args.requests, args.clients, args.safe_clients, args.phase_timeout,
                             args.request_timeout)
        for k, r in lat.items():
            if "p50" in r:
                print(f"  {k:14s} clients={r['clients']} ok={r['ok']}/{r['sent']} p50={r['p50']:.1f} ms "
                      f"p99={r['p99']:.1f} ms {r['rps']:.0f} req/s statuses={r['statuses']} errors={r['errors']}",
                      flush=True)
        a.stop()  # it may be stalled; a fresh server measures the upload
        server_errors = a.exceptions()

        ups = []
        b = Server(root, "upload")
        servers.append(b)
        b.wait_ready()
        for chunked in (False, True):
            label = f"{args.upload_mb} MiB, limit 512 MiB, " + ("chunked" if chunked else "Content-Length")
            print(f"upload: {label} ...", flush=True)
            ups.append(upload(b, big, chunked=chunked, label=label))
            print(f"  {ups[-1]}", flush=True)
        b.stop()

        c = Server(root, "limit50", {"CLOUD2CNC_MAX_UPLOAD_MB": "50"})
        servers.append(c)
        c.wait_ready()
        for chunked in (False, True):
            label = f"{args.upload_mb} MiB, limit 50 MiB, " + ("chunked" if chunked else "Content-Length")
            print(f"upload: {label} ...", flush=True)
            ups.append(upload(c, big, chunked=chunked, label=label))
            print(f"  {ups[-1]}", flush=True)

        c.stop()
        busy = run_busy(root, args)
        text = render(lat, ups, args, machine(), time.perf_counter() - t_start, server_errors,
                      load_before)
        text = splice_section(text, render_busy(busy[0], args, machine(), *busy[1:]))
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(text)
        print(f"wrote {args.out}")
        for s in servers:
            tail = s.log_tail(1500)
            if "Traceback" in tail or "ERROR" in tail:
                print(f"--- server log {s.log_path} (tail) ---\n{tail}", file=sys.stderr)
        failed = [u for u in ups if u["delta_mb"] >= LIMIT_DELTA_MB]
        wrong = [u for u, e in zip(ups, [202, 202, 413, 413]) if u["status"] != e]
        bad_lat = [k for k, r in lat.items() if "ok" in r and r["ok"] < r["requested"]]
        return 1 if failed or wrong or bad_lat or not _busy_met(busy[0]) else 0
    finally:
        for s in servers:
            s.stop()
        if args.keep:
            print(f"kept {root}")
        else:
            shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
