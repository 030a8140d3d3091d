"""`cloud2cnc run`: the pipeline in-process on one file, exit codes a script can rely on."""

from __future__ import annotations

import json
import subprocess
import sys

from tests.conftest import ROOT


def cli(*args, cwd=ROOT):
    return subprocess.run([sys.executable, "-m", "cloud2cnc.cli", *args], capture_output=True, text=True, cwd=cwd,
                          timeout=120)


def test_run_writes_design_artifacts(tmp_path):
    out = tmp_path / "out"
    r = cli("run", str(ROOT / "examples" / "dome_block.xyz"), "--out", str(out), "--set", "tool.radius_mm=2",
            "--set", "ingest.units=mm", "--until", "ingest")
    assert r.returncode == 0, r.stderr
    assert {"params.json", "cloud.ply", "ingest.json"} <= {p.name for p in out.iterdir()}
    assert json.loads((out / "params.json").read_text())["tool"]["radius_mm"] == 2
    report = json.loads((out / "ingest.json").read_text())
    assert report["counts"]["kept"] == 3000 and report["has_normals"]
    assert "ingest" in r.stderr and "done" in r.stderr
    assert not [p for p in out.iterdir() if p.name.startswith(".")]  # no scratch left behind


def test_run_reports_bad_params_and_bad_input(tmp_path):
    r = cli("run", str(ROOT / "examples" / "dome_block.xyz"), "--out", str(tmp_path / "a"), "--set", "tool.radius_mm=-1")
    assert r.returncode == 2 and "radius_mm" in r.stderr
    r = cli("run", str(ROOT / "examples" / "dome_block.xyz"), "--out", str(tmp_path / "b"), "--set", "oops")
    assert r.returncode == 2 and "group.name=value" in r.stderr
    r = cli("run", str(ROOT / "examples" / "dome_block.xyz"), "--out", str(tmp_path / "c"), "--until", "polish")
    assert r.returncode == 2 and "unknown stage" in r.stderr
    garbage = tmp_path / "garbage.ply"
    garbage.write_bytes(b"\x00\x01\x02 not a cloud" * 50)
    r = cli("run", str(garbage), "--out", str(tmp_path / "d"))
    assert r.returncode == 1 and "FAILED" in r.stderr
    r = cli("run", str(tmp_path / "missing.ply"), "--out", str(tmp_path / "e"))
    assert r.returncode == 2 and "not found" in r.stderr


def test_openapi_command_writes_the_schema(tmp_path):
    r = cli("openapi", "--output", str(tmp_path / "o.json"))
    assert r.returncode == 0, r.stderr
    assert json.loads((tmp_path / "o.json").read_text())["paths"]["/v1/jobs"]["post"]
