// Parsers for the artifact formats of DESIGN.md, free of three.js and of the DOM so that they run in a
// Web Worker: PLY (ascii, binary little/big endian, any properties, lists), OBJ (polygons), G-code,
// B-spline surfaces (surfaces.json) and point decimation. Everything returns typed arrays.

const PLY_TYPES = {
  char: ["Int8", 1], int8: ["Int8", 1], uchar: ["Uint8", 1], uint8: ["Uint8", 1],
  short: ["Int16", 2], int16: ["Int16", 2], ushort: ["Uint16", 2], uint16: ["Uint16", 2],
  int: ["Int32", 4], int32: ["Int32", 4], uint: ["Uint32", 4], uint32: ["Uint32", 4],
  float: ["Float32", 4], float32: ["Float32", 4], double: ["Float64", 8], float64: ["Float64", 8],
};

export class FormatError extends Error {}

function findHeaderEnd(bytes) {
  const needle = [101, 110, 100, 95, 104, 101, 97, 100, 101, 114]; // "end_header"
  const limit = Math.min(bytes.length - needle.length, 1 << 20);
  outer: for (let i = 0; i <= limit; i++) {
    for (let k = 0; k < needle.length; k++) if (bytes[i + k] !== needle[k]) continue outer;
    let j = i + needle.length;
    while (j < bytes.length && bytes[j] !== 10) j++;
    return { headerEnd: i, bodyStart: j + 1 };
  }
  throw new FormatError("not a PLY file: no end_header");
}

export function parsePlyHeader(bytes) {
  const { headerEnd, bodyStart } = findHeaderEnd(bytes);
  const text = new TextDecoder("latin1").decode(bytes.subarray(0, headerEnd));
  const lines = text.split(/\r?\n/).map((l) => l.trim()).filter(Boolean);
  if (lines[0] !== "ply") throw new FormatError("not a PLY file: it does not start with 'ply'");
  let format = null;
  const elements = [];
  const comments = [];
  for (const line of lines.slice(1)) {
    const w = line.split(/\s+/);
    if (w[0] === "format") format = w[1];
    else if (w[0] === "comment" || w[0] === "obj_info") comments.push(line.slice(w[0].length + 1));
    else if (w[0] === "element") elements.push({ name: w[1], count: Number(w[2]), props: [] });
    else if (w[0] === "property") {
      const el = elements[elements.length - 1];
      if (!el) throw new FormatError("PLY property before any element");
      if (w[1] === "list") {
        if (!PLY_TYPES[w[2]] || !PLY_TYPES[w[3]]) throw new FormatError(`PLY list type ${w[2]} ${w[3]} unknown`);
        el.props.push({ name: w[4], list: true, countType: w[2], type: w[3] });
      } else {
        if (!PLY_TYPES[w[1]]) throw new FormatError(`PLY property type ${w[1]} unknown`);
        el.props.push({ name: w[2], list: false, type: w[1] });
      }
    }
  }
  if (!["ascii", "binary_little_endian", "binary_big_endian"].includes(format)) {
    throw new FormatError(`PLY format ${format} unknown`);
  }
  return { format, elements, comments, bodyStart };
}

/**
 * Read every element of a PLY file. Scalar properties become Float64Array/Float32Array columns;
 * list properties become {offsets: Uint32Array(count+1), values: Uint32Array} (indices).
 */
export function readPly(buffer) {
  const bytes = new Uint8Array(buffer);
  const header = parsePlyHeader(bytes);
  const out = { comments: header.comments, elements: {} };
  if (header.format === "ascii") {
    const text = new TextDecoder("latin1").decode(bytes.subarray(header.bodyStart));
    const re = /\S+/g;
    const next = () => {
      const m = re.exec(text);
      if (!m) throw new FormatError("PLY body ends early");
      return Number(m[0]);
    };
    for (const el of header.elements) out.elements[el.name] = readElement(el, next, next);
  } else {
    const view = new DataView(buffer);
    const little = header.format === "binary_little_endian";
    let at = header.bodyStart;
    const reader = (type) => {
      const [kind, size] = PLY_TYPES[type];
      const fn = view[`get${kind}`].bind(view);
      return () => {
        if (at + size > view.byteLength) throw new FormatError("PLY body ends early");
        const v = fn(at, little);
        at += size;
        return v;
      };
    };
    for (const el of header.elements) {
      if (el.props.every((p) => !p.list)) {
        out.elements[el.name] = readScalarElementFast(el, view, at, little);
        at += el.count * el.props.reduce((s, p) => s + PLY_TYPES[p.type][1], 0);
        if (at > view.byteLength) throw new FormatError("PLY body ends early");
      } else {
        const readers = {};
        for (const p of el.props) {
          readers[p.name] = { count: p.list ? reader(p.countType) : null, value: reader(p.type) };
        }
        out.elements[el.name] = readElement(el, null, null, readers);
      }
    }
  }
  return out;
}

function readScalarElementFast(el, view, start, little) {
  const stride = el.props.reduce((s, p) => s + PLY_TYPES[p.type][1], 0);
  if (start + stride * el.count > view.byteLength) throw new FormatError("PLY body ends early");
  const cols = {};
  let off = 0;
  for (const p of el.props) {
    const [kind, size] = PLY_TYPES[p.type];
    const col = new Float64Array(el.count);
    const get = view[`get${kind}`].bind(view);
    for (let i = 0, at = start + off; i < el.count; i++, at += stride) col[i] = get(at, little);
    cols[p.name] = col;
    off += size;
  }
  return { count: el.count, cols, lists: {} };
}

function readElement(el, nextCount, nextValue, readers) {
  const cols = {}, lists = {};
  for (const p of el.props) {
    if (p.list) lists[p.name] = { offsets: new Uint32Array(el.count + 1), values: [] };
    else cols[p.name] = new Float64Array(el.count);
  }
  for (let i = 0; i < el.count; i++) {
    for (const p of el.props) {
      const r = readers ? readers[p.name] : null;
      if (p.list) {
        const n = r ? r.count() : nextCount();
        const l = lists[p.name];
        for (let k = 0; k < n; k++) l.values.push(r ? r.value() : nextValue());
        l.offsets[i + 1] = l.values.length;
      } else {
        cols[p.name][i] = r ? r.value() : nextValue();
      }
    }
  }
  for (const l of Object.values(lists)) l.values = Uint32Array.from(l.values);
  return { count: el.count, cols, lists };
}

const STD_VERTEX = new Set(["x", "y", "z", "nx", "ny", "nz", "red", "green", "blue", "alpha",
  "diffuse_red", "diffuse_green", "diffuse_blue", "r", "g", "b"]);

function colorColumns(cols) {
  const r = cols.red || cols.diffuse_red || cols.r, g = cols.green || cols.diffuse_green || cols.g;
  const b = cols.blue || cols.diffuse_blue || cols.b;
  if (!r || !g || !b) return null;
  const n = r.length;
  let max = 0;
  for (let i = 0; i < n; i++) max = Math.max(max, r[i], g[i], b[i]);
  const scale = max <= 1.0 ? 255 : 1; // float colours in 0..1
  const out = new Uint8Array(n * 3);
  for (let i = 0; i < n; i++) {
    out[3 * i] = r[i] * scale; out[3 * i + 1] = g[i] * scale; out[3 * i + 2] = b[i] * scale;
  }
  return out;
}

/** Polygon lists (offsets/values) to triangles by fans, with the source face of each triangle. */
export function triangulate(offsets, values, nFaces) {
  let nTri = 0;
  for (let f = 0; f < nFaces; f++) nTri += Math.max(0, offsets[f + 1] - offsets[f] - 2);
  const tris = new Uint32Array(nTri * 3), triFace = new Uint32Array(nTri);
  let t = 0;
  for (let f = 0; f < nFaces; f++) {
    const a = offsets[f], n = offsets[f + 1] - a;
    for (let k = 1; k + 1 < n; k++, t++) {
      tris[3 * t] = values[a]; tris[3 * t + 1] = values[a + k]; tris[3 * t + 2] = values[a + k + 1];
      triFace[t] = f;
    }
  }
  return { tris, triFace };
}

/** Unique polygon edges (not the triangulation diagonals) as vertex index pairs. */
export function polygonEdges(offsets, values, nFaces, nVerts) {
  const seen = new Set();
  const out = [];
  for (let f = 0; f < nFaces; f++) {
    const a = offsets[f], n = offsets[f + 1] - a;
    for (let k = 0; k < n; k++) {
      const u = values[a + k], v = values[a + ((k + 1) % n)];
      const key = u < v ? u * nVerts + v : v * nVerts + u;
      if (seen.has(key)) continue;
      seen.add(key);
      out.push(u, v);
    }
  }
  return Uint32Array.from(out);
}

/**
 * A PLY as display geometry: positions (Float32), normals, per-vertex colours, per-face colours,
 * extra scalar vertex properties (for heat maps), triangles and the face of each triangle.
 */
export function plyGeometry(buffer, { wantEdges = false } = {}) {
  const ply = readPly(buffer);
  const v = ply.elements.vertex;
  if (!v || !v.cols.x || !v.cols.y || !v.cols.z) throw new FormatError("PLY has no vertex x, y, z");
  const n = v.count;
  const positions = new Float32Array(n * 3);
  for (let i = 0; i < n; i++) {
    positions[3 * i] = v.cols.x[i]; positions[3 * i + 1] = v.cols.y[i]; positions[3 * i + 2] = v.cols.z[i];
  }
  let normals = null;
  if (v.cols.nx && v.cols.ny && v.cols.nz) {
    normals = new Float32Array(n * 3);
    for (let i = 0; i < n; i++) {
      normals[3 * i] = v.cols.nx[i]; normals[3 * i + 1] = v.cols.ny[i]; normals[3 * i + 2] = v.cols.nz[i];
    }
  }
  const scalars = {};
  for (const [name, col] of Object.entries(v.cols)) if (!STD_VERTEX.has(name)) scalars[name] = Float32Array.from(col);
  const out = { kind: "ply", vertexCount: n, positions, normals, colors: colorColumns(v.cols), scalars,
    comments: ply.comments, tris: null, triFace: null, faceCount: 0, faceColors: null, faceScalars: {}, edges: null };
  const f = ply.elements.face;
  if (f && f.count) {
    const list = f.lists.vertex_indices || f.lists.vertex_index || Object.values(f.lists)[0];
    if (list) {
      const { tris, triFace } = triangulate(list.offsets, list.values, f.count);
      Object.assign(out, { tris, triFace, faceCount: f.count, faceColors: colorColumns(f.cols) });
      for (const [name, col] of Object.entries(f.cols)) if (!STD_VERTEX.has(name)) out.faceScalars[name] = Float32Array.from(col);
      if (wantEdges) out.edges = polygonEdges(list.offsets, list.values, f.count, n);
    }
  }
  return out;
}

/** OBJ: vertices and polygon faces (v, v/vt, v//vn, v/vt/vn; negative indices), quads kept whole. */
export function objGeometry(text, { wantEdges = true } = {}) {
  const pos = [];
  const offsets = [0];
  const values = [];
  const lines = text.split(/\r?\n/);
  for (let i = 0; i < lines.length; i++) {
    const line = lines[i];
    const c = line.charCodeAt(0);
    if (c === 118 && line.charCodeAt(1) === 32) { // "v "
      const w = line.trim().split(/\s+/);
      pos.push(Number(w[1]), Number(w[2]), Number(w[3]));
    } else if (c === 102 && line.charCodeAt(1) === 32) { // "f "
      const w = line.trim().split(/\s+/);
      const nv = pos.length / 3;
      for (let k = 1; k < w.length; k++) {
        let idx = parseInt(w[k], 10);
        if (!Number.isFinite(idx)) throw new FormatError(`OBJ line ${i + 1}: bad face index ${w[k]}`);
        idx = idx < 0 ? nv + idx : idx - 1;
        values.push(idx);
      }
      offsets.push(values.length);
    }
  }
  const n = pos.length / 3;
  const nFaces = offsets.length - 1;
  const offs = Uint32Array.from(offsets), vals = Uint32Array.from(values);
  for (let k = 0; k < vals.length; k++) {
    if (vals[k] >= n) throw new FormatError(`OBJ face refers to vertex ${vals[k] + 1} of ${n}`);
  }
  const { tris, triFace } = triangulate(offs, vals, nFaces);
  let quadCount = 0;
  for (let f = 0; f < nFaces; f++) if (offs[f + 1] - offs[f] === 4) quadCount++;
  return { kind: "obj", vertexCount: n, positions: Float32Array.from(pos), normals: null, colors: null, scalars: {},
    tris, triFace, faceCount: nFaces, quadCount, faceColors: null, faceScalars: {},
    edges: wantEdges ? polygonEdges(offs, vals, nFaces, n) : null };
}

/** Keep at most `budget` of n points, spread evenly with a little jitter (no scan-line aliasing). */
export function decimateIndices(n, budget, seed = 12345) {
  if (n <= budget) return null;
  const out = new Uint32Array(budget);
  const step = n / budget;
  let s = seed >>> 0;
  for (let k = 0; k < budget; k++) {
    s = (Math.imul(s, 1664525) + 1013904223) >>> 0;
    out[k] = Math.min(n - 1, Math.floor((k + s / 4294967296) * step));
  }
  return out;
}

export function pickRows(arr, idx, width) {
  if (!arr || !idx) return arr;
  const out = new arr.constructor(idx.length * width);
  for (let k = 0; k < idx.length; k++) for (let c = 0; c < width; c++) out[k * width + c] = arr[idx[k] * width + c];
  return out;
}

/** A point cloud for display: at most `budget` points; the rest are dropped evenly. */
export function decimateGeometry(geo, budget) {
  const idx = decimateIndices(geo.vertexCount, budget);
  if (!idx) return { ...geo, shownCount: geo.vertexCount };
  const scalars = {};
  for (const [k, v] of Object.entries(geo.scalars || {})) scalars[k] = pickRows(v, idx, 1);
  return { ...geo, positions: pickRows(geo.positions, idx, 3), normals: pickRows(geo.normals, idx, 3),
    colors: pickRows(geo.colors, idx, 3), scalars, shownCount: idx.length };
}

// ---------------------------------------------------------------- G-code

/**
 * G-code to line segments in the program's frame (mm): cutting moves and rapids separately.
 * Handles G0/G1/G2/G3 (arcs in G17 by I/J or R), G90/G91, G20/G21, comments in () and after ;.
 */
export function parseGcode(text) {
  const cuts = [], rapids = [];
  let x = 0, y = 0, z = 0, motion = 0, absolute = true, scale = 1, plane = 17, started = false;
  const lines = text.split(/\r?\n/);
  let lineCount = 0;
  for (const raw of lines) {
    const line = raw.replace(/\([^)]*\)/g, "").replace(/;.*$/, "").toUpperCase();
    if (!line.trim() || line.trim() === "%") continue;
    lineCount++;
    const words = line.match(/[A-Z][+-]?(\d+\.?\d*|\.\d+)/g) || [];
    const w = {};
    let moveWord = false;
    for (const word of words) {
      const letter = word[0], val = Number(word.slice(1));
      if (letter === "G") {
        if ([0, 1, 2, 3].includes(val)) { motion = val; moveWord = true; }
        else if (val === 90) absolute = true;
        else if (val === 91) absolute = false;
        else if (val === 20) scale = 25.4;
        else if (val === 21) scale = 1;
        else if (val === 17 || val === 18 || val === 19) plane = val;
      } else if ("XYZIJKR".includes(letter)) w[letter] = val * scale;
    }
    if (w.X === undefined && w.Y === undefined && w.Z === undefined) { void moveWord; continue; }
    const nx = w.X === undefined ? x : absolute ? w.X : x + w.X;
    const ny = w.Y === undefined ? y : absolute ? w.Y : y + w.Y;
    const nz = w.Z === undefined ? z : absolute ? w.Z : z + w.Z;
    if (!started) { // the first positioning move starts somewhere unknown: no segment
      started = true; x = nx; y = ny; z = nz;
      continue;
    }
    const target = motion === 0 ? rapids : cuts;
    if ((motion === 2 || motion === 3) && plane === 17) {
      arc(target, x, y, z, nx, ny, nz, w, motion === 2);
    } else {
      target.push(x, y, z, nx, ny, nz);
    }
    x = nx; y = ny; z = nz;
  }
  return { cuts: Float32Array.from(cuts), rapids: Float32Array.from(rapids), lineCount };
}

function arc(out, x0, y0, z0, x1, y1, z1, w, clockwise) {
  let cx, cy;
  if (w.I !== undefined || w.J !== undefined) {
    cx = x0 + (w.I || 0); cy = y0 + (w.J || 0);
  } else if (w.R !== undefined) {
    const dx = x1 - x0, dy = y1 - y0, d = Math.hypot(dx, dy);
    const r = Math.abs(w.R);
    if (d === 0 || d > 2 * r + 1e-9) { out.push(x0, y0, z0, x1, y1, z1); return; }
    const hgt = Math.sqrt(Math.max(0, r * r - (d / 2) ** 2));
    const sign = (clockwise ? 1 : -1) * (w.R < 0 ? -1 : 1);
    cx = (x0 + x1) / 2 + sign * hgt * (dy / d);
    cy = (y0 + y1) / 2 - sign * hgt * (dx / d);
  } else { out.push(x0, y0, z0, x1, y1, z1); return; }
  const r = Math.hypot(x0 - cx, y0 - cy);
  let a0 = Math.atan2(y0 - cy, x0 - cx), a1 = Math.atan2(y1 - cy, x1 - cx);
  let sweep = a1 - a0;
  if (clockwise && sweep >= 0) sweep -= 2 * Math.PI;
  if (!clockwise && sweep <= 0) sweep += 2 * Math.PI;
  const n = Math.max(2, Math.ceil(Math.abs(sweep) / (Math.PI / 18)));
  let px = x0, py = y0, pz = z0;
  for (let k = 1; k <= n; k++) {
    const t = k / n, a = a0 + sweep * t;
    const qx = k === n ? x1 : cx + r * Math.cos(a), qy = k === n ? y1 : cy + r * Math.sin(a);
    const qz = z0 + (z1 - z0) * t;
    out.push(px, py, pz, qx, qy, qz);
    px = qx; py = qy; pz = qz;
  }
}

// ---------------------------------------------------------------- B-splines

function findSpan(n, p, u, U) { // n = number of control points - 1 (The NURBS Book, A2.1)
  if (u >= U[n + 1]) return n;
  if (u <= U[p]) return p;
  let low = p, high = n + 1, mid = (low + high) >> 1;
  while (u < U[mid] || u >= U[mid + 1]) {
    if (u < U[mid]) high = mid; else low = mid;
    mid = (low + high) >> 1;
  }
  return mid;
}

function basis(span, u, p, U) { // A2.2
  const N = new Float64Array(p + 1), left = new Float64Array(p + 1), right = new Float64Array(p + 1);
  N[0] = 1;
  for (let j = 1; j <= p; j++) {
    left[j] = u - U[span + 1 - j];
    right[j] = U[span + j] - u;
    let saved = 0;
    for (let r = 0; r < j; r++) {
      const den = right[r + 1] + left[j - r];
      const tmp = den === 0 ? 0 : N[r] / den;
      N[r] = saved + right[r + 1] * tmp;
      saved = left[j - r] * tmp;
    }
    N[j] = saved;
  }
  return N;
}

/** Tessellate one surfaces.json entry into a (res+1)² grid of points and its triangles. */
export function tessellateSurface(s, res = 24) {
  const [p, q] = s.degree || [3, 3];
  const U = s.knots_u, V = s.knots_v;
  let P = s.control_points;
  const nu = U.length - p - 1, nv = V.length - q - 1;
  if (!Array.isArray(P) || !P.length) throw new FormatError(`surface of patch ${s.patch}: no control points`);
  if (P.length !== nu || P[0].length !== nv) {
    if (P.length === nv && P[0].length === nu) P = P[0].map((_, j) => P.map((row) => row[j]));
    else throw new FormatError(`surface of patch ${s.patch}: a ${P.length}×${P[0].length} control net does not match `
      + `${U.length} u-knots and ${V.length} v-knots of degree ${p}, ${q}`);
  }
  const n = res + 1;
  const positions = new Float32Array(n * n * 3);
  const u0 = U[p], u1 = U[nu], v0 = V[q], v1 = V[nv];
  const bu = [], bv = [];
  for (let i = 0; i < n; i++) {
    const u = u0 + (u1 - u0) * (i / res);
    const su = findSpan(nu - 1, p, u, U);
    bu.push([su, basis(su, u, p, U)]);
    const v = v0 + (v1 - v0) * (i / res);
    const sv = findSpan(nv - 1, q, v, V);
    bv.push([sv, basis(sv, v, q, V)]);
  }
  for (let i = 0; i < n; i++) {
    const [su, Nu] = bu[i];
    for (let j = 0; j < n; j++) {
      const [sv, Nv] = bv[j];
      let x = 0, y = 0, z = 0;
      for (let a = 0; a <= p; a++) {
        const row = P[su - p + a];
        for (let b = 0; b <= q; b++) {
          const w = Nu[a] * Nv[b], c = row[sv - q + b];
          x += w * c[0]; y += w * c[1]; z += w * c[2];
        }
      }
      const k = 3 * (i * n + j);
      positions[k] = x; positions[k + 1] = y; positions[k + 2] = z;
    }
  }
  const tris = new Uint32Array(res * res * 6);
  let t = 0;
  for (let i = 0; i < res; i++) {
    for (let j = 0; j < res; j++) {
      const a = i * n + j, b = a + 1, c = a + n, d = c + 1;
      tris.set([a, c, b, b, c, d], t);
      t += 6;
    }
  }
  return { positions, tris };
}

/** All surfaces of surfaces.json, merged, with the patch of each vertex. */
export function surfacesGeometry(doc, res) {
  const list = Array.isArray(doc?.surfaces) ? doc.surfaces : [];
  if (!list.length) throw new FormatError("surfaces.json has no surfaces");
  const parts = [];
  let nv = 0, nt = 0;
  const errors = [];
  for (const s of list) {
    try {
      const g = tessellateSurface(s, res);
      parts.push({ g, patch: s.patch });
      nv += g.positions.length / 3; nt += g.tris.length;
    } catch (err) { errors.push(err.message); }
  }
  const positions = new Float32Array(nv * 3), tris = new Uint32Array(nt), vertexPatch = new Int32Array(nv);
  let vo = 0, to = 0;
  for (const { g, patch } of parts) {
    positions.set(g.positions, vo * 3);
    for (let k = 0; k < g.tris.length; k++) tris[to + k] = g.tris[k] + vo;
    vertexPatch.fill(Number.isInteger(patch) ? patch : -1, vo, vo + g.positions.length / 3);
    vo += g.positions.length / 3; to += g.tris.length;
  }
  const fitErrors = list.map((s) => s.max_error_mm).filter((e) => typeof e === "number");
  return { positions, tris, vertexPatch, surfaceCount: parts.length, errors,
    maxError: fitErrors.length ? Math.max(...fitErrors) : null,
    tolerance: typeof doc?.tolerance_mm === "number" ? doc.tolerance_mm : null };
}
