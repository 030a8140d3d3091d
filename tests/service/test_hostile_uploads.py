"""Malformed and hostile uploads and parameter sets.

Each gets a 4xx problem at upload, or — where only reading the whole file
can tell — a job whose `ingest` stage fails with a message a user can act on.
None gets a 5xx; none succeeds on garbage. Ingest runs in-process through the
same runner the Celery task calls.
"""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from core.config import Settings
from service.app import create_app
from tests.cam.test_io_scanners import (
    WKT_FTUS,
    WKT_GEOGRAPHIC,
    scanner_bytes,
    wkt_vlr,
    write_e57_raw,
    write_e57_without_scans,
    write_las,
)
from tests.conftest import xyz_bytes
from tests.service.test_api import assert_problem
from worker.runner import run_stage


@pytest.fixture
def settings(tmp_path: Path) -> Settings:
    # These cases are about ingest; the jobs run only that stage so that "succeeded" means ingest did.
    return Settings(data_dir=tmp_path / "data", min_points=10, max_points=5000, max_upload_mb=1.0,
                    pipeline="ingest")


@pytest.fixture
def client(settings):
    with TestClient(create_app(settings, reconcile=False)) as c:
        yield c


def post(client, data: bytes, params: str | None = None, name: str = "part.bin", headers=None):
    form = {"params": params} if params is not None else {}
    return client.post("/v1/jobs", files={"file": (name, data, "application/octet-stream")}, data=form,
                       headers=headers or {})


def ply_header(n: int, fmt: str = "binary_little_endian", props: str = "float x\nproperty float y\nproperty float z",
               faces: int = 0) -> bytes:
    head = f"ply\nformat {fmt} 1.0\nelement vertex {n}\nproperty {props}\n"
    if faces:
        head += f"element face {faces}\nproperty list uchar int vertex_indices\n"
    return (head + "end_header\n").encode()


def cube_points(n: int = 100) -> np.ndarray:
    return np.random.default_rng(3).uniform(-5, 5, size=(n, 3))


# -- refused at upload -------------------------------------------------------------------------

UPLOAD_CASES = {
    "empty file": (b"", None, 422, "empty-file"),
    "random bytes": (np.random.default_rng(0).bytes(4096), None, 415, "unsupported-format"),
    "png image": (b"\x89PNG\r\n\x1a\n" + bytes(200), None, 415, "unsupported-format"),
    "zip archive": (b"PK\x03\x04" + bytes(200), None, 415, "unsupported-format"),
    "gzip": (zlib.compress(xyz_bytes(50)), None, 415, "unsupported-format"),
    "json document": (b'{"points": [[1,2,3]]}', None, 415, "unsupported-format"),
    "html page": (b"<!doctype html><html><body>hi</body></html>", None, 415, "unsupported-format"),
    "prose": (b"This is a letter, not a point cloud.\nKind regards\n", None, 415, "unsupported-format"),
    "pdf": (b"%PDF-1.7\n%\xe2\xe3\xcf\xd3\n1 0 obj\n", None, 415, "unsupported-format"),
    "elf binary": (b"\x7fELF\x02\x01\x01" + bytes(300), None, 415, "unsupported-format"),
    "params not json": (xyz_bytes(50), "{tool: radius}", 422, "invalid-params"),
    "params is a list": (xyz_bytes(50), "[1, 2]", 422, "invalid-params"),
    "params unknown group": (xyz_bytes(50), '{"laser": {"power": 3}}', 422, "invalid-params"),
    "params unknown field": (xyz_bytes(50), '{"tool": {"diameter": 6}}', 422, "invalid-params"),
    "negative tool radius": (xyz_bytes(50), '{"tool": {"radius_mm": -3}}', 422, "invalid-params"),
    "radius as text": (xyz_bytes(50), '{"tool": {"radius_mm": "three"}}', 422, "invalid-params"),
    "NaN radius": (xyz_bytes(50), '{"tool": {"radius_mm": NaN}}', 422, "invalid-params"),
    "infinite scallop": (xyz_bytes(50), '{"toolpath": {"scallop_height_mm": 1e400}}', 422, "invalid-params"),
    "zero scallop": (xyz_bytes(50), '{"toolpath": {"scallop_height_mm": 0}}', 422, "invalid-params"),
    "unknown units": (xyz_bytes(50), '{"ingest": {"units": "furlong"}}', 422, "invalid-params"),
    "unknown dialect": (xyz_bytes(50), '{"toolpath": {"dialect": "heidenhain"}}', 422, "invalid-params"),
    "sharp angle 200": (xyz_bytes(50), '{"segment": {"sharp_angle_deg": 200}}', 422, "invalid-params"),
    "target faces huge": (xyz_bytes(50), '{"remesh": {"target_faces": 1e12}}', 422, "invalid-params"),
    "group is a number": (xyz_bytes(50), '{"tool": 3}', 422, "invalid-params"),
    "over the size cap": (b"0 0 0\n" * 250_000, None, 413, "payload-too-large"),
    "params over 64 KiB": (xyz_bytes(50), '{"x": "' + "a" * 70_000 + '"}', 413, "payload-too-large"),
}


@pytest.mark.parametrize("case", list(UPLOAD_CASES))
def test_refused_at_upload(client, case):
    data, params, status, slug = UPLOAD_CASES[case]
    assert_problem(post(client, data, params), status, slug)


def test_a_recognised_foreign_format_says_what_it_is(client):
    body = assert_problem(post(client, b"PK\x03\x04" + bytes(200), name="scan.zip"), 415, "unsupported-format")
    assert "ZIP archive" in body["detail"] and "unpack" in body["detail"]


def test_no_file_part(client):
    r = client.post("/v1/jobs", data={"params": "{}"}, files={"other": ("x", b"1 2 3", "text/plain")})
    assert_problem(r, 422, "missing-file")


def test_not_multipart(client):
    assert_problem(client.post("/v1/jobs", json={"file": "0 0 0"}), 415, "unsupported-media-type")


def test_two_file_parts(client):
    files = [("file", ("a.xyz", xyz_bytes(20), "text/plain")), ("file", ("b.xyz", xyz_bytes(20), "text/plain"))]
    assert_problem(client.post("/v1/jobs", files=files), 422, "validation-error")


def test_truncated_multipart_body(client):
    body = b"--XyZ\r\nContent-Disposition: form-data; name=\"file\"; filename=\"a.xyz\"\r\n\r\n" + xyz_bytes(20)
    r = client.post("/v1/jobs", content=body, headers={"Content-Type": "multipart/form-data; boundary=XyZ"})
    assert_problem(r, 400, "malformed-multipart")


def test_lying_content_length_is_refused_before_reading(client):
    body = b"--XyZ--\r\n"
    r = client.post("/v1/jobs", content=body, headers={"Content-Type": "multipart/form-data; boundary=XyZ",
                                                        "Content-Length": str(10**12)})
    assert r.status_code in (400, 413)
    assert r.headers["content-type"].startswith("application/problem+json")


def test_bad_idempotency_keys(client):
    assert_problem(post(client, xyz_bytes(30), headers={"Idempotency-Key": "x" * 300}), 422, "validation-error")
    assert_problem(post(client, xyz_bytes(30), headers={"Idempotency-Key": "   "}), 400, "invalid-idempotency-key")


def test_path_traversal_filename_is_only_a_label(client, settings, tmp_path):
    r = post(client, xyz_bytes(40), name="../../etc/passwd.ply")
    assert r.status_code == 202, r.text
    job = r.json()
    assert job["input"]["name"] == "passwd.ply"
    assert {a["name"] for a in job["artifacts"]} == {"input.xyz", "params.json"}  # format from content
    stored = [p for p in settings.data_dir.rglob("*") if p.is_file()]
    assert all(settings.data_dir.resolve() in p.resolve().parents for p in stored)
    assert not any("passwd" in p.name for p in stored)


def test_nothing_stored_is_lost_after_refusals(client):
    good = post(client, xyz_bytes(40)).json()
    for data, params, *_ in list(UPLOAD_CASES.values())[:8]:
        post(client, data, params)
    assert client.get(f"/v1/jobs/{good['id']}/artifacts/input.xyz").content == xyz_bytes(40)


# -- found while ingesting ---------------------------------------------------------------------

def _binary_ply(points: np.ndarray, endian: str = "<") -> bytes:
    fmt = "binary_little_endian" if endian == "<" else "binary_big_endian"
    return ply_header(len(points), fmt) + points.astype(endian + "f4").tobytes()


def _pcd_compressed() -> bytes:
    return (b"# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 100\nHEIGHT 1\n"
            b"VIEWPOINT 0 0 0 1 0 0 0\nPOINTS 100\nDATA binary_compressed\n" + bytes(64))


def _stl_bad_count() -> bytes:
    return b"\0" * 80 + struct.pack("<I", 10) + bytes(50 * 10)


_E57 = scanner_bytes(".e57", write_e57_raw, cube_points(300) / 100)
_LAS = scanner_bytes(".las", write_las, cube_points(300))
_LAZ = scanner_bytes(".laz", write_las, cube_points(3000))

INGEST_CASES = {
    "truncated binary ply": (_binary_ply(cube_points(100))[:-200], "truncated"),
    "header claims more vertices (binary)": (ply_header(5000) + cube_points(100).astype("<f4").tobytes(), "5000"),
    "header claims more vertices (ascii)": (ply_header(500, "ascii") + b"1 2 3\n" * 20, "500"),
    "all NaN rows": (b"nan nan nan\n" * 200, "finite"),
    "fewer points than the minimum": (xyz_bytes(5), "10"),
    "more points than the maximum": (xyz_bytes(6000), "5000"),
    "text row mid-file": (xyz_bytes(50) + b"1.0 two 3.0\n" + xyz_bytes(50), "line"),
    "ragged columns": (b"1 2 3\n" * 30 + b"1 2\n" + b"1 2 3\n" * 30, "line"),
    "compressed pcd": (_pcd_compressed(), "binary_compressed"),
    "obj face index out of range": (b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n", "index"),
    "ply face index out of range": (ply_header(3, "ascii", faces=1) + b"0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n", "index"),
    "mesh of only degenerate faces": (b"v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\nf 1 1 2\n", "face"),
    "truncated e57": (_E57[: len(_E57) // 2], "truncated"),
    "truncated las": (_LAS[:-100], "truncated"),
    "truncated laz": (_LAZ[: len(_LAZ) // 2], "truncated"),
    "e57 without a scan": (scanner_bytes(".e57", write_e57_without_scans), "no 3D scan"),
    "las in degrees": (scanner_bytes(".las", write_las, cube_points(300), vlrs=[wkt_vlr(WKT_GEOGRAPHIC)],
                                     global_wkt=True), "degrees"),
    "las over the point limit": (scanner_bytes(".las", write_las, cube_points(6000)), "5000"),
}


@pytest.mark.parametrize("case", list(INGEST_CASES))
def test_ingest_fails_with_an_actionable_message(client, settings, case):
    data, needle = INGEST_CASES[case]
    r = post(client, data)
    if r.status_code != 202:  # caught even earlier: fine, as long as it is a 4xx problem
        assert 400 <= r.status_code < 500 and r.headers["content-type"].startswith("application/problem+json")
        return
    job_id = r.json()["id"]
    run_stage(settings, job_id, "ingest")
    job = client.get(f"/v1/jobs/{job_id}").json()
    assert job["status"] == "failed", job
    stage = job["stages"][0]
    assert stage["status"] == "failed"
    detail = stage["error"]["detail"]
    assert stage["error"]["type"] == "urn:cloud2cnc:problem:stage-failed", detail
    assert needle.lower() in detail.lower(), detail
    assert job["error"]["stage"] == "ingest"


def test_nan_rows_are_dropped_and_counted(client, settings):
    rows = xyz_bytes(100) + b"nan 1 2 0 0 1\ninf 0 0 0 0 1\n"
    job_id = post(client, rows).json()["id"]
    run_stage(settings, job_id, "ingest")
    job = client.get(f"/v1/jobs/{job_id}").json()
    assert job["status"] == "succeeded", job
    report = client.get(f"/v1/jobs/{job_id}/artifacts/ingest.json").json()
    assert report["counts"]["kept"] == 100
    assert sum(d["count"] for d in report["dropped"]) == 2


def test_big_endian_ply_and_inch_units(client, settings):
    pts = cube_points(64)
    job_id = post(client, _binary_ply(pts, ">"), '{"ingest": {"units": "inch"}}').json()["id"]
    run_stage(settings, job_id, "ingest")
    report = client.get(f"/v1/jobs/{job_id}/artifacts/ingest.json").json()
    assert report["units"] == "inch"
    np.testing.assert_allclose(report["bbox_mm"]["min"], pts.astype(">f4").min(axis=0) * 25.4, rtol=1e-6)


def test_mesh_upload_takes_the_mesh_path(client, settings):
    import trimesh

    stl = trimesh.creation.box(extents=(10, 20, 30)).export(file_type="stl")
    job_id = post(client, stl, name="box.stl").json()["id"]
    run_stage(settings, job_id, "ingest")
    job = client.get(f"/v1/jobs/{job_id}").json()
    assert job["status"] == "succeeded", job
    names = {a["name"] for a in job["artifacts"]}
    assert "mesh_raw.ply" in names and "cloud.ply" not in names


@pytest.mark.parametrize("fmt", ["e57", "las"])
def test_scanner_uploads_state_their_unit_and_are_read_in_mm(client, settings, fmt):
    pts = cube_points(200) / 100  # a 10 cm cube: metres in E57, US survey feet by the LAS file's CRS
    data = (scanner_bytes(".e57", write_e57_raw, pts) if fmt == "e57" else
            scanner_bytes(".las", write_las, pts, vlrs=[wkt_vlr(WKT_FTUS)], global_wkt=True))
    # ingest.units says inch, but these files state their own unit, which wins (and the report says so).
    r = post(client, data, '{"ingest": {"units": "inch"}}', name="scan.bin")
    assert r.status_code == 202, r.text
    job_id = r.json()["id"]
    assert r.json()["input"]["format"] == fmt and f"input.{fmt}" in {a["name"] for a in r.json()["artifacts"]}
    run_stage(settings, job_id, "ingest")
    assert client.get(f"/v1/jobs/{job_id}").json()["status"] == "succeeded"
    report = client.get(f"/v1/jobs/{job_id}/artifacts/ingest.json").json()
    mm = 1000.0 if fmt == "e57" else 1200 / 3937 * 1000.0
    assert report["units"] == "mm" and report["format"] == fmt
    assert any("converted to mm" in note for note in report["notes"])
    # Within LAS's half quantum (0.0005 ft) and far from any other unit's factor.
    np.testing.assert_allclose(report["bbox_mm"]["min"], pts.min(axis=0) * mm, atol=1e-3 * mm)
