"""G-code: dialect rules, our parser round trip, pygcode on every dialect, LinuxCNC's rs274 on ours."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from cam.gcode import DIALECTS, GCodeError, parse_program, write_program
from cam.gcode.moves import FEED, PLUNGE, RAPID, MoveList
from cam.gcode.setup import Setup
from cam.params import ToolParams, ToolpathParams
from cam.plan.patch_job import plan_patches
from cam.spline import analytic

HEADER = {"cloud2cnc finishing program": "job test-job, setup 1, patches 1", "tool": "ball end mill radius 3 mm, T1",
          "target scallop": "0.1600 mm", "certified scallop bound": "0.159000 mm", "units": "mm", "dialect": "x",
          "generator": "cloud2cnc plan 1",
          # What a header may say: brackets and a ';' (Fanuc ends a block at ';', pygcode starts a comment).
          "bound": "measured on the samples (exact sweep); verify measures again"}


@pytest.fixture(scope="module")
def moves() -> MoveList:
    plan = plan_patches([1], [analytic.cylinder(20.0, 12.0, 50.0)], [Setup(1, np.eye(3), np.zeros(3))],
                    ToolParams(radius_mm=3.0), ToolpathParams(scallop_height_mm=0.16))
    return plan.setups[0].moves


@pytest.mark.parametrize("dialect", sorted(DIALECTS))
def test_dialect_rules_and_round_trip(moves, dialect):
    text = write_program(moves, dialect=dialect, header={**HEADER, "dialect": dialect}, tool_number=3,
                         spindle_rpm=10000, feed_mm_min=900, plunge_mm_min=200)
    lines = text.splitlines()
    assert "G21" in text and "G90" in text and "G17" in text and "M5" in lines
    assert ("T3 M6" in lines) == (dialect != "grbl")
    if dialect == "grbl":
        assert max(map(len, lines)) < 80 and "M6" not in text
    if dialect == "fanuc":
        assert lines[0] == lines[-1] == "%" and lines[1] == "O0001" and "M30" in lines
    else:
        assert lines[-1] == "M2"
    # 4 decimals on every coordinate, never a bare integer (Fanuc would read it as microns).
    for word in " ".join(x for x in lines if not x.startswith("(")).split():
        if word[0] in "XYZ":
            assert len(word.split(".")[1]) == 4
    prog = parse_program(text)
    assert prog.header_value("certified scallop bound").lower() == "0.159000 mm"
    cutting = moves.points[moves.kind == FEED]
    np.testing.assert_allclose(prog.end[~prog.rapid & (prog.feed == 900)], cutting, atol=6e-5)
    assert np.all(prog.feed[~prog.rapid & (prog.feed != 900)] == 200)


def test_parser_refuses_what_it_does_not_model():
    for bad in ("G0 X0 Y0 Z5\nG2 X1 Y1 I1 J0 F100\n", "G0 X0 Y0 Z5\nG1 X1\n", "G0 X0 Y0 Z5\nG0 A10\n", "X1 Y2\n"):
        with pytest.raises(GCodeError, match="line 2|line 1"):
            parse_program(bad)
    prog = parse_program("G20 G90\nG0 X0 Y0 Z1 (inch)\nG91 G1 X1 F10 ; relative\n")
    np.testing.assert_allclose(prog.end[-1], [25.4, 0, 25.4])


def test_writer_checks_its_inputs():
    m = MoveList(np.array([[0, 0, 5.0], [0, 0, 1.0], [1, 0, 0.0]]), np.array([RAPID, PLUNGE, FEED], np.int8),
                 np.array([-1, -1, 1]), 5.0)
    with pytest.raises(ValueError, match="feed_mm_min"):
        write_program(m, header={}, feed_mm_min=0)
    with pytest.raises(ValueError, match="dialect"):
        write_program(m, header={}, dialect="heidenhain")


@pytest.mark.parametrize("dialect", sorted(DIALECTS))
def test_every_dialect_parses_with_pygcode(moves, dialect):
    pygcode = pytest.importorskip("pygcode")
    text = write_program(moves, dialect=dialect, header={**HEADER, "dialect": dialect})
    machine = pygcode.Machine()
    count = 0
    for raw in text.splitlines():
        if raw.strip() in ("%",) or raw.startswith("O"):
            continue
        line = pygcode.Line(raw)
        machine.process_block(line.block)
        count += 1
    assert count > 50
    # pygcode followed the same absolute moves: its final position is our last rapid up.
    last = moves.points[-1]
    pos = machine.pos.values
    assert pos["X"] == pytest.approx(last[0], abs=1e-4) and pos["Z"] == pytest.approx(last[2], abs=1e-4)


def linuxcnc_rs274(cache: Path) -> tuple[Path, dict[str, str]]:
    """LinuxCNC's stand-alone interpreter from the Debian package, unpacked (not installed) under `cache`.

    Uses $CLOUD2CNC_LINUXCNC_ROOT when it points at an unpacked root; otherwise runs
    `apt-get download linuxcnc-uspace libboost-python1.74.0` and `dpkg -x`; skips when that cannot work.
    """
    root = Path(os.environ.get("CLOUD2CNC_LINUXCNC_ROOT", cache / "root"))
    binary = root / "usr" / "bin" / "rs274"
    if not binary.exists():
        if "CLOUD2CNC_LINUXCNC_ROOT" in os.environ:
            pytest.skip(f"CLOUD2CNC_LINUXCNC_ROOT={root} holds no usr/bin/rs274")
        if not (shutil.which("apt-get") and shutil.which("dpkg")):
            pytest.skip("apt-get/dpkg not available: cannot fetch LinuxCNC's rs274")
        cache.mkdir(parents=True, exist_ok=True)
        try:
            subprocess.run(["apt-get", "download", "linuxcnc-uspace", "libboost-python1.74.0"], cwd=cache,
                           check=True, capture_output=True, timeout=300)
            for deb in cache.glob("*.deb"):
                subprocess.run(["dpkg", "-x", str(deb), str(root)], check=True, capture_output=True, timeout=300)
        except (subprocess.SubprocessError, OSError) as exc:
            pytest.skip(f"could not fetch linuxcnc-uspace with apt-get download (run apt-get update?): {exc}")
    libs = [str(p) for p in (root / "usr" / "lib", root / "usr" / "lib" / "x86_64-linux-gnu") if p.exists()]
    env = {**os.environ, "LD_LIBRARY_PATH": ":".join(libs + [os.environ.get("LD_LIBRARY_PATH", "")])}
    return binary, env


def test_linuxcnc_rs274_accepts_the_program(moves, tmp_path_factory):
    binary, env = linuxcnc_rs274(tmp_path_factory.getbasetemp() / "linuxcnc")
    work = tmp_path_factory.mktemp("rs274")
    (work / "tool.tbl").write_text("T1 P1 Z0 D6 ;ball end mill R3\n")
    good = work / "program.nc"
    good.write_text(write_program(moves, dialect="linuxcnc", header=HEADER))
    run = subprocess.run([str(binary), "-t", str(work / "tool.tbl"), "-g", str(good)], env=env, capture_output=True,
                         text=True, timeout=120, stdin=subprocess.DEVNULL)
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-2000:]
    feeds = [x for x in run.stdout.splitlines() if "STRAIGHT_FEED" in x]
    assert len(feeds) == int(np.sum(moves.kind != RAPID))
    # The interpreter does complain about a broken program (the check can fail).
    bad = work / "bad.nc"
    bad.write_text("G21 G90\nG1 X1 Y1\nM2\n")
    run = subprocess.run([str(binary), "-t", str(work / "tool.tbl"), "-g", str(bad)], env=env, capture_output=True,
                         text=True, timeout=120, stdin=subprocess.DEVNULL)
    assert run.returncode != 0
