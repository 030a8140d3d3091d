"""IGES 5.3 export: the fixed-column layout, and an independent CAD kernel (OpenCASCADE) reading it back."""

from __future__ import annotations

from datetime import datetime, timezone

import numpy as np
import pytest

from cam.io.iges import iges_bytes, write_iges
from cam.spline.surface import clamped_uniform_knots, make_bspline_surface

WHEN = datetime(2024, 5, 1, 12, 30, 0, tzinfo=timezone.utc)


def _surfaces():
    rng = np.random.default_rng(0)
    a = make_bspline_surface(rng.normal(size=(6, 4, 3)) * 10, [0, 0, 0, 0, 0.3, 0.6, 1, 1, 1, 1],
                             clamped_uniform_knots(4))
    b = make_bspline_surface(rng.normal(size=(5, 7, 3)) * 10 + 50, clamped_uniform_knots(5),
                             [0, 0, 0, 0, 0.2, 0.2, 0.5, 1, 1, 1, 1])
    return [a, b]


def test_layout_is_80_columns_with_consistent_sections_and_pointers():
    text = iges_bytes(_surfaces(), labels=[3, 7], created=WHEN).decode("ascii")
    lines = text.splitlines()
    assert all(len(line) == 80 for line in lines)
    sections = [line[72] for line in lines]
    assert sections == sorted(sections, key="SGDPT".index)  # S, G, D, P, T in order
    for letter in "SGDP":
        seq = [int(line[73:]) for line in lines if line[72] == letter]
        assert seq == list(range(1, len(seq) + 1))
    term = lines[-1]
    counts = {term[i]: int(term[i + 1:i + 8]) for i in range(0, 32, 8)}
    assert counts == {k: sections.count(k) for k in "SGDP"}
    glob = "".join(line[:72] for line in lines if line[72] == "G")
    assert glob.startswith("1H,,1H;,") and ",2,2HMM," in glob and "15H20240501.123000" in glob
    de = [line for line in lines if line[72] == "D"]
    assert [int(de[i][:8]) for i in range(0, 4, 2)] == [128, 128]
    assert int(de[3][64:72]) == 7  # the label is the entity subscript
    params = [line for line in lines if line[72] == "P"]
    start, count = int(de[2][8:16]), int(de[3][24:32])
    assert all(int(line[64:72]) == 3 for line in params[start - 1:start - 1 + count])  # back-pointer to DE 3
    first = "".join(line[:64].rstrip() for line in params if int(line[64:72]) == 1)
    assert first.startswith("128,5,3,3,3,0,0,1,0,0,0.0,0.0,0.0,0.0,0.3,0.6,1.0,")
    assert first.endswith(",0.0,1.0,0.0,1.0;")


def test_bad_input_is_refused(tmp_path):
    with pytest.raises(ValueError, match="one label per surface"):
        iges_bytes(_surfaces(), labels=[1])
    assert not list(tmp_path.iterdir())


def test_opencascade_reads_back_surfaces_that_evaluate_to_ours(tmp_path):
    ocp = pytest.importorskip("OCP", reason="cadquery-ocp (OpenCASCADE) is not installed: pip install cadquery-ocp")
    from OCP.BRep import BRep_Tool
    from OCP.IFSelect import IFSelect_RetDone
    from OCP.IGESControl import IGESControl_Reader
    from OCP.TopAbs import TopAbs_FACE
    from OCP.TopExp import TopExp_Explorer
    from OCP.TopoDS import TopoDS

    assert ocp
    surfaces = _surfaces()
    path = write_iges(tmp_path / "surfaces.igs", surfaces, labels=[3, 7], created=WHEN)
    reader = IGESControl_Reader()
    assert reader.ReadFile(str(path)) == IFSelect_RetDone
    assert reader.TransferRoots() == 2
    explorer = TopExp_Explorer(reader.OneShape(), TopAbs_FACE)
    rng = np.random.default_rng(1)
    read = 0
    while explorer.More():
        surf = BRep_Tool.Surface_s(TopoDS.Face(explorer.Current()))
        ours = surfaces[read]
        assert surf.DynamicType().Name() == "Geom_BSplineSurface"
        assert surf.Bounds() == (0.0, 1.0, 0.0, 1.0)
        u, v = rng.uniform(0, 1, 25), rng.uniform(0, 1, 25)
        theirs = np.array([[surf.Value(a, b).X(), surf.Value(a, b).Y(), surf.Value(a, b).Z()] for a, b in zip(u, v)])
        np.testing.assert_allclose(theirs, ours.evaluate(u, v), atol=1e-9)
        read += 1
        explorer.Next()
    assert read == 2
