"""STEP AP214 export: the Part 21 structure, and an independent CAD kernel (OpenCASCADE) reading it back."""

from __future__ import annotations

import re
from datetime import UTC, datetime

import numpy as np
import pytest

from cam.fit.patches import fit_patches
from cam.io.step import step_bytes, write_step
from cam.params import FitParams
from cam.spline.surface import make_bspline_surface
from tests.cam.test_fit_shapes import case, cylinder

WHEN = datetime(2024, 5, 1, 12, 30, 0, tzinfo=UTC)


def _plane(origin=(10.0, -5.0, 2.5), size=(100.0, 50.0)):
    """A bilinear patch: the rectangle `size` mm in x by y at `origin`, u along x and v along y."""
    x0, y0, z0 = origin
    cp = np.array([[[x0, y0, z0], [x0, y0 + size[1], z0]],
                   [[x0 + size[0], y0, z0], [x0 + size[0], y0 + size[1], z0]]])
    return make_bspline_surface(cp, [0, 0, 1, 1], [0, 0, 1, 1], degree=(1, 1))


def _bicubic():
    """A bicubic patch on (u, v) in [2, 5] x [-1, 1]: 7 x 5 control points, interior knots in both
    directions (one of them double), the net a smooth bump on a 60 x 40 mm base."""
    ku = [2, 2, 2, 2, 2.5, 3.5, 3.5, 5, 5, 5, 5]
    kv = [-1, -1, -1, -1, 0.25, 1, 1, 1, 1]
    x, y = np.meshgrid(np.linspace(0, 60, 7), np.linspace(0, 40, 5), indexing="ij")
    z = 8 * np.sin(x / 20) * np.cos(y / 25) + 0.1 * x
    return make_bspline_surface(np.stack([x, y, z], axis=-1), ku, kv)


def _fitted():
    """Two bicubic patches our fitter makes on a cylinder section (r = 25 mm), C0 along their shared row."""
    V, ids, MV, MF = case(cylinder(25.0), (30, 15), (14, 7), refine=3)
    result = fit_patches(V, [ids[:8], ids[7:]], MV, MF, FitParams(tolerance_mm=0.032))
    assert result.over_tolerance == []
    return [p.surface for p in result.patches]


def _entities(text: str) -> dict[int, str]:
    """The DATA section as {id: 'TYPE(...)'} with line breaks removed."""
    data = text.split("\nDATA;\n", 1)[1].split("\nENDSEC;", 1)[0].replace("\n", "")
    found = dict(re.findall(r"#(\d+)=(.*?);(?=#|$)", data))
    return {int(k): v for k, v in found.items()}


def _ref(text: str) -> list[int]:
    """The entity ids an attribute text refers to, in order."""
    return [int(r) for r in re.findall(r"#(\d+)", text)]


def test_part21_structure_units_and_references():
    surfaces = [_plane(), _bicubic()]
    text = step_bytes(surfaces, labels=[3, 7], created=WHEN, organization="O'Neil \\ Müller").decode("ascii")
    lines = text.splitlines()
    assert lines[:2] == ["ISO-10303-21;", "HEADER;"] and lines[-2:] == ["ENDSEC;", "END-ISO-10303-21;"]
    assert "FILE_SCHEMA(('AUTOMOTIVE_DESIGN { 1 0 10303 214 1 1 1 1 }'));" in lines
    assert "'2024-05-01T12:30:00+00:00'" in text
    assert "('O''Neil \\\\ M\\X2\\00FC\\X0\\ller')" in text  # Part 21 escapes: '' , \\ and \X2\
    assert all(len(line) <= 80 for line in lines)
    ent = _entities(text)
    assert sorted(ent) == list(range(1, len(ent) + 1))
    # Every reference names an entity of the file.
    refs = {int(r) for body in ent.values() for r in re.findall(r"#(\d+)", body)}
    assert refs <= set(ent)
    kinds = [body.split("(", 1)[0] for body in ent.values()]
    assert kinds.count("B_SPLINE_SURFACE_WITH_KNOTS") == kinds.count("ADVANCED_FACE") == 2
    assert kinds.count("OPEN_SHELL") == 2 and kinds.count("EDGE_CURVE") == 8
    for once in ("SHELL_BASED_SURFACE_MODEL", "MANIFOLD_SURFACE_SHAPE_REPRESENTATION", "PRODUCT",
                 "PRODUCT_DEFINITION", "PRODUCT_DEFINITION_SHAPE", "SHAPE_DEFINITION_REPRESENTATION"):
        assert kinds.count(once) == 1, once
    assert "(LENGTH_UNIT()NAMED_UNIT(*)SI_UNIT(.MILLI.,.METRE.))" in ent.values()
    (bicubic,) = [b for b in ent.values() if b.startswith("B_SPLINE_SURFACE_WITH_KNOTS('patch 7'")]
    # Knots as distinct values with multiplicities, u then v.
    assert bicubic.endswith(",(4,1,2,4),(4,1,4),(2.0,2.5,3.5,5.0),(-1.0,0.25,1.0),.UNSPECIFIED.)")
    # The net as 7 lists (u) of 5 points (v).
    net = re.search(r"'patch 7',3,3,\((.*)\),\.UNSPECIFIED\.,", bicubic).group(1)
    rows = re.findall(r"\(([#\d,]+)\)", net)
    assert [len(r.split(",")) for r in rows] == [5] * 7
    first = ent[int(rows[1].split(",")[0][1:])]  # control point [1, 0]
    z = repr(float(_bicubic().control_points[1, 0, 2])).upper()
    assert first == f"CARTESIAN_POINT('',(10.0,0.0,{z}))"



def test_the_outer_bound_runs_counter_clockwise_about_the_normal():
    # The plane patch has u along x and v along y, so its normal S_u x S_v is +z: its outer bound must
    # be a closed loop of its four corners running counter-clockwise seen from +z.
    ent = _entities(step_bytes([_plane()], created=WHEN).decode("ascii"))
    (face,) = [b for b in ent.values() if b.startswith("ADVANCED_FACE(")]
    assert face.endswith(",.T.)")
    bound = ent[_ref(face)[0]]
    assert bound.startswith("FACE_OUTER_BOUND(") and bound.endswith(",.T.)")
    loop = []
    for oriented in _ref(ent[_ref(bound)[0]]):
        body = ent[oriented]
        start, end, _curve = _ref(ent[_ref(body)[0]])
        if body.endswith(".F.)"):
            start, end = end, start
        points = [ent[_ref(ent[v])[0]].split(",", 1)[1][:-1] for v in (start, end)]  # "(x,y,z)"
        loop.append([np.array(p.strip("()").split(","), dtype=float) for p in points])
    assert len(loop) == 4
    assert all(np.array_equal(a[1], b[0]) for a, b in zip(loop, loop[1:] + loop[:1]))  # closed
    xy = np.array([a[0][:2] for a in loop])
    signed = 0.5 * float(np.sum(xy[:, 0] * np.roll(xy[:, 1], -1) - np.roll(xy[:, 0], -1) * xy[:, 1]))
    assert signed == pytest.approx(5000.0)

def test_bad_input_is_refused_and_nothing_is_written(tmp_path):
    with pytest.raises(ValueError, match="one label per surface"):
        write_step(tmp_path / "s.step", [_plane()], labels=[1, 2])
    s = _plane()
    unclamped = type("S", (), {"degree": (1, 1), "knots_u": np.array([0.0, 0.5, 1.0, 1.5]),
                               "knots_v": s.knots_v, "control_points": s.control_points})
    with pytest.raises(ValueError, match="patch 0: knots_u must be clamped"):
        write_step(tmp_path / "s.step", [unclamped])
    bad = type("S", (), {"degree": (1, 1), "knots_u": s.knots_u, "knots_v": s.knots_v,
                         "control_points": np.where(np.eye(2)[:, :, None] > 0, np.nan, s.control_points)})
    with pytest.raises(ValueError, match="NaN"):
        write_step(tmp_path / "s.step", [bad])
    assert not list(tmp_path.iterdir())


# --- OpenCASCADE reads it back --------------------------------------------------------------------------


def _read_back(path):
    """(faces, surfaces, length units, checks-clean) as OpenCASCADE's STEP reader gives them."""
    pytest.importorskip("OCP", reason="cadquery-ocp (OpenCASCADE) is not installed: pip install cadquery-ocp")
    from OCP.BRep import BRep_Tool
    from OCP.BRepCheck import BRepCheck_Analyzer
    from OCP.IFSelect import IFSelect_RetDone
    from OCP.OCP.collections import Sequence_TCollection_AsciiString
    from OCP.STEPControl import STEPControl_Reader
    from OCP.TopAbs import TopAbs_FACE
    from OCP.TopExp import TopExp_Explorer
    from OCP.TopoDS import TopoDS

    reader = STEPControl_Reader()
    assert reader.ReadFile(str(path)) == IFSelect_RetDone
    assert reader.TransferRoots() == 1
    clean = reader.WS().ModelCheckList(True).IsEmpty(False)  # no load or transfer fails
    units = [Sequence_TCollection_AsciiString() for _ in range(3)]
    reader.FileUnits(*units)
    lengths = [units[0].Value(i + 1).ToCString() for i in range(units[0].Length())]
    shape = reader.OneShape()
    assert BRepCheck_Analyzer(shape).IsValid()
    faces, explorer = [], TopExp_Explorer(shape, TopAbs_FACE)
    while explorer.More():
        faces.append(TopoDS.Face(explorer.Current()))
        explorer.Next()
    return faces, [BRep_Tool.Surface_s(f) for f in faces], lengths, clean


def _grid(surf, n=21):
    (u0, u1), (v0, v1) = surf.domain
    u, v = np.meshgrid(np.linspace(u0, u1, n), np.linspace(v0, v1, n), indexing="ij")
    return u.ravel(), v.ravel()


def _assert_same_surfaces(theirs_list, ours_list):
    assert len(theirs_list) == len(ours_list)
    for theirs, ours in zip(theirs_list, ours_list):
        assert theirs.DynamicType().Name() == "Geom_BSplineSurface"
        (u0, u1), (v0, v1) = ours.domain
        assert theirs.Bounds() == (u0, u1, v0, v1)  # the same parameters, not rescaled
        assert (theirs.UDegree(), theirs.VDegree()) == ours.degree
        u, v = _grid(ours)
        pts = np.array([[(p := theirs.Value(a, b)).X(), p.Y(), p.Z()] for a, b in zip(u, v)])
        np.testing.assert_allclose(pts, ours.evaluate(u, v), rtol=0, atol=1e-9)


def _normals(faces, ours_list):
    """Per face, the cosine between OpenCASCADE's outward face normal and our S_u x S_v at mid-domain."""
    from OCP.BRepAdaptor import BRepAdaptor_Surface
    from OCP.BRepLProp import BRepLProp_SLProps
    from OCP.TopAbs import TopAbs_REVERSED

    cosines = []
    for face, ours in zip(faces, ours_list):
        (u0, u1), (v0, v1) = ours.domain
        um, vm = (u0 + u1) / 2, (v0 + v1) / 2
        props = BRepLProp_SLProps(BRepAdaptor_Surface(face), um, vm, 1, 1e-9)
        n = props.Normal()
        theirs = np.array([n.X(), n.Y(), n.Z()]) * (-1 if face.Orientation() == TopAbs_REVERSED else 1)
        cosines.append(float(theirs @ ours.normals(np.array(um), np.array(vm))))
    return cosines


def test_a_plane_patch_comes_back_in_mm_at_its_size(tmp_path):
    from_ocp = pytest.importorskip("OCP.GProp")
    from OCP.BRep import BRep_Tool
    from OCP.BRepGProp import BRepGProp
    from OCP.TopAbs import TopAbs_VERTEX
    from OCP.TopExp import TopExp_Explorer
    from OCP.TopoDS import TopoDS

    plane = _plane()
    faces, theirs, lengths, clean = _read_back(write_step(tmp_path / "plane.step", [plane], created=WHEN))
    assert clean and lengths == ["millimetre"] and len(faces) == 1
    _assert_same_surfaces(theirs, [plane])
    # The face is the whole rectangle, bounded the right way round: 100 mm x 50 mm = 5000 mm^2.
    props = from_ocp.GProp_GProps()
    BRepGProp.SurfaceProperties_s(faces[0], props)
    assert props.Mass() == pytest.approx(5000.0, rel=1e-12)
    BRepGProp.LinearProperties_s(faces[0], props)
    assert props.Mass() == pytest.approx(300.0, rel=1e-12)  # its four edges: the perimeter
    corners, explorer = set(), TopExp_Explorer(faces[0], TopAbs_VERTEX)
    while explorer.More():
        p = BRep_Tool.Pnt_s(TopoDS.Vertex(explorer.Current()))
        corners.add((p.X(), p.Y(), p.Z()))
        explorer.Next()
    assert corners == {(10.0, -5.0, 2.5), (110.0, -5.0, 2.5), (110.0, 45.0, 2.5), (10.0, 45.0, 2.5)}
    assert _normals(faces, [plane]) == [pytest.approx(1.0)]


def test_a_bicubic_patch_with_interior_knots_evaluates_as_ours(tmp_path):
    surfaces = [_bicubic(), _plane()]
    faces, theirs, lengths, clean = _read_back(write_step(tmp_path / "s.step", surfaces, labels=[7, 3]))
    assert clean and lengths == ["millimetre"] and len(faces) == 2
    _assert_same_surfaces(theirs, surfaces)
    assert _normals(faces, surfaces) == [pytest.approx(1.0)] * 2


def test_patches_our_fitter_made_evaluate_as_ours(tmp_path):
    surfaces = _fitted()
    faces, theirs, lengths, clean = _read_back(write_step(tmp_path / "s.step", surfaces, labels=[10, 20]))
    assert clean and lengths == ["millimetre"] and len(faces) == 2
    _assert_same_surfaces(theirs, surfaces)
    assert _normals(faces, surfaces) == [pytest.approx(1.0)] * 2
    # Their shared border (C0 to 1e-9 mm) is one edge to a CAD kernel that sews them: 8 free edges become
    # 6, one pair joined.
    from OCP.BRepBuilderAPI import BRepBuilderAPI_Sewing

    sewing = BRepBuilderAPI_Sewing(1e-6)
    for face in faces:
        sewing.Add(face)
    sewing.Perform()
    assert (sewing.NbFreeEdges(), sewing.NbContigousEdges()) == (6, 1)



def test_the_service_serves_it_as_model_step():
    from core.stages import STAGES
    from service.present import media_type

    assert "surfaces.step" in next(s for s in STAGES if s.name == "fit").outputs
    assert media_type("surfaces.step") == "model/step"  # the IANA media type of ISO 10303-21 files
