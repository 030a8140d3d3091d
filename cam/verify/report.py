"""The setup sheet (`report.html`): what a machinist needs at the machine, from what verify measured.

One self-contained, printable HTML page (inline CSS, inline SVG pictures from `cam.verify.picture`; no
script, no network): the part, each setup's orientation on the table with its tool axis, the tools,
each program's path length, air moves and estimated machining time, the scallop certificate, the
finished share of the reachable surface with its coverage picture, and every unfinished area by reason.
Every number of verify.json it shows carries its exact value in a `data-value` attribute.
"""

from __future__ import annotations

from dataclasses import dataclass
from html import escape

import numpy as np

from cam.gcode.parser import ParsedProgram
from cam.gcode.setup import Setup
from cam.verify.part import format_share
from cam.verify.picture import Arrow, Plane, is_closed, render_svg, simplify_mesh

__all__ = ["COVERAGE_CLASSES", "DEFAULT_RAPID_MM_MIN", "ProgramStats", "classify_faces", "measure_moves",
           "render_report"]

#: Triangles the pictures of the part and of its coverage keep at most, and those of the setups (thumbnails):
#: the sheet stays a few hundred kB whatever the mesh.
PICTURE_FACES, SETUP_PICTURE_FACES = 3000, 1200

#: The rapid rate the machining time assumes (G0 moves carry no feed; a machine's is in its manual).
DEFAULT_RAPID_MM_MIN = 5000.0

#: Coverage classes of the part's faces: index → (name, colour). -1 (no sample) is drawn light grey.
COVERAGE_CLASSES = (("finished", (0.23, 0.66, 0.36)), ("over target", (0.95, 0.66, 0.10)),
                    ("not cut", (0.84, 0.27, 0.27)), ("unreachable", (0.55, 0.60, 0.66)))


#: The sheet's style: A4 portrait, readable in black and white too (the verdict and classes are words as well).
SHEET_CSS = """
@page { size: A4; margin: 12mm; }
* { box-sizing: border-box; }
body { font: 10.5pt/1.4 system-ui, -apple-system, "Segoe UI", Roboto, sans-serif; color: #1d232b; margin: 0 auto;
  max-width: 190mm; padding: 8mm 6mm; background: #fff; }
h1 { font-size: 20pt; margin: 0; } h2 { font-size: 13pt; margin: 0 0 4pt; border-bottom: 1.5pt solid #2463b5;
  padding-bottom: 2pt; } h3 { font-size: 11pt; margin: 8pt 0 3pt; }
.sub { margin: 0 0 4pt; color: #5b6672; }
.verdict { font-weight: 600; padding: 4pt 8pt; border-radius: 4pt; display: inline-block; margin: 2pt 0 6pt; }
.verdict.ok { background: #e3f4e8; color: #1f6b39; } .verdict.bad { background: #fde8e6; color: #9b2418; }
section { margin: 0 0 10pt; break-inside: avoid; page-break-inside: avoid; }
.row { display: flex; gap: 10pt; align-items: flex-start; flex-wrap: wrap; }
.row > div { flex: 1 1 60mm; }
svg.part-picture { max-width: 100%; height: auto; border: 0.6pt solid #d5dbe2; border-radius: 3pt; background: #fbfcfd; }
.pic-label { font: 10px sans-serif; fill: #3b4550; }
table { border-collapse: collapse; width: 100%; margin: 2pt 0 4pt; font-size: 9.5pt; }
th, td { text-align: left; padding: 2pt 5pt; border-bottom: 0.5pt solid #d5dbe2; vertical-align: top; }
thead th { background: #eef2f6; }
table.kv th { width: 45%; font-weight: 500; color: #3b4550; }
.num { font-variant-numeric: tabular-nums; white-space: nowrap; }
.note, footer { color: #5b6672; font-size: 8.5pt; }
.legend .sw { display: inline-block; width: 9pt; height: 9pt; margin: 0 3pt 0 8pt; vertical-align: -1pt;
  border: 0.5pt solid #555; }
.problems li { color: #9b2418; }
.summary { font-weight: 600; }
.sub-row { padding-left: 12pt; color: #3b4550; }
@media print { body { padding: 0; max-width: none; } .setup { break-before: auto; }
  * { -webkit-print-color-adjust: exact; print-color-adjust: exact; } }
"""


@dataclass(frozen=True)
class ProgramStats:
    """One program's moves: lengths in mm, times in minutes (cutting at its F words, rapids at the stated rate)."""

    name: str
    setup: int
    role: str
    tool_radius_mm: float
    cutting_mm: float
    rapid_mm: float
    cutting_min: float
    rapid_min: float
    moves: int

    @property
    def total_min(self) -> float:
        return self.cutting_min + self.rapid_min


def measure_moves(program: ParsedProgram, *, rapid_mm_min: float = DEFAULT_RAPID_MM_MIN) -> tuple[float, float, float, float]:
    """Cutting and rapid path lengths of a program and the time each takes.

    Parameters
    ----------
    program : ParsedProgram
        Its moves (feeds in mm/min, NaN on rapids).
    rapid_mm_min : float
        The machine's rapid rate, > 0.

    Returns
    -------
    cutting_mm, rapid_mm, cutting_min, rapid_min : float
        Lengths of the G1 and G0 moves; minutes at each G1 move's feed and at the rapid rate.
    """
    if not rapid_mm_min > 0:
        raise ValueError(f"rapid_mm_min must be > 0, got {rapid_mm_min}")
    length = np.linalg.norm(program.end - program.start, axis=1)
    cut = ~program.rapid
    feed = program.feed[cut]
    if np.any(~(feed > 0)):
        raise ValueError(f"a cutting move has feed {feed[~(feed > 0)][0]} mm/min; time needs a positive feed")
    return (float(length[cut].sum()), float(length[program.rapid].sum()),
            float((length[cut] / feed).sum()), float(length[program.rapid].sum() / rapid_mm_min))


def classify_faces(sample_face: np.ndarray, left_mm: np.ndarray, reach: np.ndarray, n_faces: int, *,
                   target_mm: float) -> np.ndarray:
    """Each face's coverage class (`COVERAGE_CLASSES`): the class holding most of its samples.

    Parameters
    ----------
    sample_face : (k,) int
        The face each sample lies on.
    left_mm : (k,) float
        Material left per sample (+inf where no pass came near).
    reach : (k,) bool
        Whether the main ball reaches each sample.
    n_faces : int
    target_mm : float
        The scallop height a sample counts as finished within.

    Returns
    -------
    (n_faces,) int8
        0 finished (by whichever ball), 1 over target, 2 not cut (reachable, no pass near), 3 unreachable by
        the main ball and not finished; -1 for a face without samples.
    """
    left = np.asarray(left_mm, dtype=np.float64)
    reach = np.asarray(reach, dtype=bool)
    cls = np.where(left <= target_mm, 0, np.where(~reach, 3, np.where(np.isfinite(left), 1, 2)))
    votes = np.zeros((n_faces, len(COVERAGE_CLASSES)), dtype=np.int64)
    np.add.at(votes, (np.asarray(sample_face, dtype=np.int64), cls), 1)
    return np.where(votes.sum(axis=1) > 0, votes.argmax(axis=1), -1).astype(np.int8)


def _val(value, text: str, key: str = "") -> str:
    """A number on the sheet with its exact value alongside (tests and scripts read `data-value`)."""
    if value is None:
        return '<span class="num">—</span>'
    k = f' data-key="{escape(key)}"' if key else ""
    return f'<span class="num"{k} data-value="{escape(repr(value))}">{escape(text)}</span>'


def _mm(v, key: str = "", digits: int = 3) -> str:
    return _val(v, f"{v:.{digits}f} mm", key) if v is not None else _val(None, "")


def _pct(v, key: str = "") -> str:
    return _val(v, format_share(v), key) if v is not None else _val(None, "")


def _area(v, key: str = "") -> str:
    return _val(v, f"{v:,.1f} mm²", key)


def _minutes(m: float) -> str:
    s = round(m * 60)
    return f"{s // 3600} h {s % 3600 // 60:02d} min" if s >= 3600 else f"{s // 60} min {s % 60:02d} s"


def _table(head: list[str], rows: list[list[str]], cls: str = "") -> str:
    th = "".join(f"<th>{h}</th>" for h in head)
    body = "".join("<tr>" + "".join(f"<td>{c}</td>" for c in r) + "</tr>" for r in rows)
    return f'<table class="{cls}"><thead><tr>{th}</tr></thead><tbody>{body}</tbody></table>'


def _kv(rows: list[tuple[str, str]]) -> str:
    return '<table class="kv"><tbody>' + "".join(f"<tr><th>{k}</th><td>{v}</td></tr>" for k, v in rows) + "</tbody></table>"


_PART_VIEW = np.array([-1.0, 1.4, -0.9])  # from the front right, above
_BELOW_VIEW = np.array([-1.0, 1.4, 0.9])


def _part_pictures(V: np.ndarray, F: np.ndarray, face_class: np.ndarray | None, *, cull: bool) -> tuple[str, str]:
    size = float(np.linalg.norm(V.max(axis=0) - V.min(axis=0))) or 1.0
    o = V.min(axis=0) - 0.08 * size
    axes = tuple(Arrow(tuple(o), tuple(o + 0.22 * size * e), c, n)
                 for e, c, n in zip(np.eye(3), ("#c0392b", "#27864a", "#2463b5"), "xyz"))
    part = render_svg(V, F, direction=_PART_VIEW, up=(0, 0, 1), arrows=axes, width_px=420, height_px=320,
                      title="the part (mesh.ply), part frame", key="part", cull_back=cull)
    if face_class is None:
        return part, ""
    palette = np.array([c for _, c in COVERAGE_CLASSES] + [(0.85, 0.86, 0.88)])
    colors = palette[np.where(face_class < 0, len(COVERAGE_CLASSES), face_class)]
    cover = "".join(render_svg(V, F, direction=d, up=(0, 0, 1), face_colors=colors, width_px=320, height_px=260,
                               title=f"coverage, seen from {w}", key=f"cov{k}", cull_back=cull)
                    for k, (d, w) in enumerate(((_PART_VIEW, "above"), (_BELOW_VIEW, "below"))))
    return part, cover


def _setup_picture(V: np.ndarray, F: np.ndarray, setup: Setup, *, cull: bool) -> str:
    M = setup.to_machine(V)
    lo, hi = M.min(axis=0), M.max(axis=0)
    size = float(np.linalg.norm(hi - lo)) or 1.0
    m = 0.12 * size
    z = lo[2]
    table = Plane(((lo[0] - m, lo[1] - m, z), (hi[0] + m, lo[1] - m, z), (hi[0] + m, hi[1] + m, z),
                   (lo[0] - m, hi[1] + m, z)), label="table")
    o = np.array([lo[0] - m, lo[1] - m, z])
    axes = tuple(Arrow(tuple(o), tuple(o + 0.25 * size * e), c, n)
                 for e, c, n in zip(np.eye(3), ("#c0392b", "#27864a", "#2463b5"), "XYZ"))
    c = 0.5 * (lo + hi)
    tool = Arrow((c[0], c[1], hi[2] + 0.55 * size), (c[0], c[1], hi[2] + 0.06 * size), "#7d3cbd", "tool axis")
    return render_svg(M, F, direction=_PART_VIEW, up=(0, 0, 1), arrows=axes + (tool,), planes=(table,),
                      width_px=320, height_px=300, title=f"setup {setup.id} on the machine",
                      key=f"setup{setup.id}", cull_back=cull)


def _unfinished_rows(verify: dict, tool: dict) -> list[list[str]]:
    """verify's unfinished area by reason, nested as verify measures it (the unreachable split by what else
    happened there), each with its share of the part."""
    un = dict(verify.get("unfinished_mm2") or {})
    total = verify.get("area_mm2") or 1.0

    def row(key: str, label: str, indent: bool = False) -> list[str]:
        v = un.pop(key)
        return [('<span class="sub-row">… ' if indent else "<span>") + escape(label) + "</span>", _area(v, key),
                _val(v / total, format_share(v / total))]

    rows = []
    if "not_planned_mm2" in un:
        rows.append(row("not_planned_mm2", "reachable by the main ball, but no program leaves it within the target"))
    if "unreachable_by_main_ball_mm2" in un:
        rows.append(row("unreachable_by_main_ball_mm2", "the main ball cannot reach it from any setup"))
        for key, label in (("finished_outside_main_reach_mm2", "of which finished all the same"),
                           ("left_for_rest_tool_mm2", "of which the rest ball reaches, but no program finishes"),
                           ("unreachable_by_any_ball_mm2", "of which no ball of this job reaches" if tool.get(
                               "rest_radius_mm") else "of which no ball reaches (no rest ball is set)")):
            if key in un and (key != "left_for_rest_tool_mm2" or tool.get("rest_radius_mm")):
                rows.append(row(key, label, indent=True))

    if not tool.get("rest_radius_mm"):
        un.pop("left_for_rest_tool_mm2", None)  # nothing is left for a rest ball the job does not have
    for key in list(un):  # reasons a later verify may add
        if isinstance(un[key], (int, float)):
            rows.append(row(key, key.removesuffix("_mm2").replace("_", " ")))
    return rows


def _plan_note(item) -> str:
    """One `unmachined` / `partial` entry of the plan, as words."""
    if not isinstance(item, dict):
        return escape(str(item))
    text = f"patch {item['patch']}" if "patch" in item else ""
    if isinstance(item.get("kept"), (int, float)):
        text += f" (kept {100 * item['kept']:.0f} % of it)"
    if item.get("reason"):
        text += f" — {item['reason']}"
    return escape(text.strip(" —") or str(item))


def _legend() -> str:
    items = "".join(f'<span class="sw" style="background:rgb({",".join(str(round(255 * x)) for x in c)})"></span>'
                    f"{escape(n)} " for n, c in COVERAGE_CLASSES)
    return f'<p class="legend">{items}</p>'


def render_report(*, title: str, verify: dict, setup_doc: dict, setups: list[Setup], programs: list[ProgramStats],
                  vertices: np.ndarray, faces: np.ndarray, face_class: np.ndarray | None, tool: dict,
                  toolpath: dict, rapid_mm_min: float = DEFAULT_RAPID_MM_MIN) -> str:
    """The setup sheet as one HTML page.

    Parameters
    ----------
    title : str
        What the sheet is of (a job id, a file name); escaped here.
    verify : dict
        verify.json's content.
    setup_doc : dict
        setup.json's content (per setup: `program`, `rest_program`, `partial`, `unmachined`, `tool_axis`).
    setups : list of Setup
        Its setups, in the same order.
    programs : list of ProgramStats
    vertices, faces : (n, 3) float, (m, 3) int
        The part (mesh.ply), mm, part frame.
    face_class : (m,) int or None
        Coverage class per face (`classify_faces`); None: no coverage picture.
    tool, toolpath : dict
        The job's `tool` and `toolpath` parameter groups.
    rapid_mm_min : float
        The rapid rate the times assume (stated on the sheet).

    Returns
    -------
    str
        The HTML document.
    """
    V = np.asarray(vertices, dtype=np.float64)
    F = np.asarray(faces, dtype=np.int64)
    size = V.max(axis=0) - V.min(axis=0) if len(V) else np.zeros(3)
    # one simplified mesh for every picture (the setups' are it turned onto the table)
    full, closed = V, is_closed(F) if len(F) else False
    V, F, source = simplify_mesh(V, F, max_faces=PICTURE_FACES)
    part_svg, cover_svg = _part_pictures(V, F, None if face_class is None else np.asarray(face_class)[source],
                                         cull=closed)
    Vt, Ft, _ = simplify_mesh(V, F, max_faces=SETUP_PICTURE_FACES)
    passed = bool(verify.get("passed"))
    fin = verify.get("finished_share_of_reachable")
    verdict = "passed" if passed else "not passed"
    r = verify.get("tool_radius_mm", tool.get("radius_mm"))

    head = (f'<header><h1>Setup sheet</h1><p class="sub">{escape(title)}</p>'
            f'<p class="verdict {"ok" if passed else "bad"}">verify: {verdict} — finished {_pct(fin, "finished_share_of_reachable")} '
            f'of what a {r:g} mm ball can reach ({_pct(verify.get("reachable_share"), "reachable_share")} of the part)</p>'
            "</header>")
    part = (f'<section class="part"><h2>The part</h2><div class="row">{part_svg}<div>'
            + _kv([("size (x × y × z)", " × ".join(f"{s:.1f}" for s in size) + " mm"),
                   ("surface area", _area(verify.get("area_mm2"), "area_mm2")),
                   ("setups", str(len(setups))), ("programs", str(len(programs)))])
            + "</div></div></section>")

    tools = [["main ball", f"T{tool.get('tool_number', 1)}", _mm(tool.get("radius_mm"), digits=3),
              f"{2 * tool['radius_mm']:g} mm", f"{tool.get('spindle_rpm', 0):,.0f} rpm",
              f"{tool.get('feed_mm_min', 0):,.0f} / {tool.get('plunge_mm_min', 0):,.0f} mm/min"]]
    if tool.get("rest_radius_mm"):
        tools.append(["rest ball", f"T{tool.get('rest_tool_number', 2)}", _mm(tool["rest_radius_mm"], digits=3),
                      f"{2 * tool['rest_radius_mm']:g} mm", f"{tool.get('spindle_rpm', 0):,.0f} rpm",
                      f"{tool.get('feed_mm_min', 0):,.0f} / {tool.get('plunge_mm_min', 0):,.0f} mm/min"])
    tools_html = ('<section class="tools"><h2>Tools</h2>'
                  + _table(["tool", "number", "radius", "diameter", "spindle", "feed / plunge"], tools) + "</section>")

    total = sum(p.total_min for p in programs)
    prog_rows = [[f"<code>{escape(p.name)}</code>", str(p.setup), escape(p.role), f"{p.tool_radius_mm:g} mm",
                  f"{p.moves:,}", _val(p.cutting_mm, f"{p.cutting_mm / 1000:,.2f} m", "cutting_mm"),
                  _val(p.rapid_mm, f"{p.rapid_mm / 1000:,.2f} m", "rapid_mm"),
                  _val(p.total_min, _minutes(p.total_min), "machining_min")] for p in programs]
    prog_html = ('<section class="programs"><h2>Programs</h2>'
                 + _table(["file", "setup", "tool", "ball", "moves", "path (cutting)", "air moves (G0)", "time"],
                          prog_rows)
                 + f'<p class="note">Time: each cutting move at its own F word, rapids at an assumed '
                   f'{rapid_mm_min:,.0f} mm/min; no acceleration, tool changes or dwell. Total '
                 + _val(total, _minutes(total), "total_machining_min") + ".</p></section>")

    per = {p["program"]: p for p in verify.get("programs", [])}
    cert_rows = [[f"<code>{escape(n)}</code>", _mm(p.get("certified_scallop_mm")), _mm(p.get("max_gouge_mm"), digits=4),
                  _mm(p.get("max_rapid_gouge_mm"), digits=4)] for n, p in per.items()]
    target = verify.get("target_scallop_mm", toolpath.get("scallop_height_mm"))
    cert = ('<section class="certificate"><h2>Certificate</h2>'
            + _kv([("scallop target", _mm(target, "target_scallop_mm")),
                   ("certified bound (program headers)", _mm(verify.get("certified_scallop_mm"), "certified_scallop_mm")),
                   ("measured max scallop (finished area)", _mm(verify.get("max_scallop_mm"), "max_scallop_mm")),
                   ("measured p99 scallop", _mm(verify.get("p99_scallop_mm"), "p99_scallop_mm")),
                   ("largest left on the reachable", _mm(verify.get("max_left_on_reachable_mm"), "max_left_on_reachable_mm")),
                   ("deepest gouge (cutting / rapid)", _mm(verify.get("max_gouge_mm"), "max_gouge_mm", 4) + " / "
                    + _mm(verify.get("max_rapid_gouge_mm"), "max_rapid_gouge_mm", 4))])
            + _table(["program", "certified bound", "gouge", "rapid gouge"], cert_rows) + "</section>")

    un_rows = _unfinished_rows(verify, tool)
    for where, entry in [("plan", setup_doc)] + [(f"setup {s.id}", e) for e, s in zip(setup_doc.get("setups", []), setups)]:
        for kind in ("unmachined", "partial"):
            for item in entry.get(kind) or []:
                un_rows.append([f"{where}, {kind}: {_plan_note(item)}", "", ""])
    problems = "".join(f"<li>{escape(str(p))}</li>" for p in verify.get("problems", []))
    coverage = (f'<section class="coverage"><h2>Coverage</h2><p class="summary">{escape(str(verify.get("summary", "")))}</p>'
                + _kv([("reachable by the main ball", _pct(verify.get("reachable_share"), "reachable_share")),
                       ("finished of the reachable", _pct(fin, "finished_share_of_reachable")),
                       ("finished of the whole part", _pct(verify.get("finished_share"), "finished_share")),
                       ("required (toolpath.min_finished_share)", _pct(verify.get("min_finished_share"), "min_finished_share"))])
                + (f'<div class="row pics">{cover_svg}</div>{_legend()}' if cover_svg else "")
                + "<h3>Unfinished areas</h3>" + _table(["reason", "area", "of the part"], un_rows, "unfinished")
                + (f'<h3>Problems</h3><ul class="problems">{problems}</ul>' if problems else "") + "</section>")

    setup_html = []
    for entry, setup in zip(setup_doc.get("setups", []), setups):
        axis = entry.get("tool_axis") or setup.tool_axis_part.tolist()
        mine = [p for p in programs if p.setup == setup.id]
        rows = [("tool axis (part frame)", "(" + ", ".join(f"{a + 0.0:+.3f}" for a in np.round(axis, 3)) + ")"),
                ("rotation (part → machine)", "<br>".join(" ".join(f"{x + 0.0:+.3f}" for x in row) for row in np.round(setup.rotation, 3))),
                ("translation", " ".join(f"{x + 0.0:+.2f}" for x in np.round(setup.translation, 2)) + " mm"),
                ("base", f"the part's lowest point on the table: machine Z = "
                         f"{float(setup.to_machine(full)[:, 2].min()) + 0.0:.2f} mm" if len(full) else "—"),
                ("programs", ", ".join(f"<code>{escape(p.name)}</code> ({_minutes(p.total_min)})" for p in mine) or "—"),
                ("patches", str(len(entry.get("patches") or [])))]
        setup_html.append(f'<section class="setup"><h2>Setup {setup.id}</h2><div class="row">'
                          f"{_setup_picture(Vt, Ft, setup, cull=closed)}<div>{_kv(rows)}</div></div></section>")

    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<title>Setup sheet — {escape(title)}</title><style>{SHEET_CSS}</style></head><body>"
            + head + part + tools_html + prog_html + cert + coverage + "".join(setup_html)
            + "<footer>cloud2cnc verify: every figure measured on the G-code against mesh.ply.</footer></body></html>\n")
